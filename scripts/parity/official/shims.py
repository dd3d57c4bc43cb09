"""Math-preserving shims that let the official LHM++ modules run on a CPU, and the recorders of
the official forward's two random choices (shared/reference/official-forward.md).

No official file is edited. What is replaced is either never called on the forward path (import
stubs: any call raises), a CUDA-only helper with a CPU equivalent of the same math
(`torch_scatter.segment_csr`), or a source of inputs (the SMPL-X skinning module, which reads
licensed files: it returns the given query points, normals and part masks). Widths that the
official code fixes in its constructors (DINOv2 variants, the DPT head inside
`PatchDPT4DecoderOnly`) can be reduced for small fixtures; the classes stay the official ones.

`install(official_dir)` must run before anything imports `core`.
"""

import importlib.abc
import importlib.machinery
import os
import sys
import types
from functools import partial

import torch

# Modules that are imported but never called on the forward path.
STUBBED = ("pytorch3d", "diff_gaussian_rasterization", "pointops_cuda", "tqlt", "gsplat", "xformers")


class _Stub:
    """Stands for any attribute of a stubbed module: calling it raises."""

    def __init__(self, name):
        self._name = name

    def __getattr__(self, item):
        return _Stub(f"{self._name}.{item}")

    def __call__(self, *args, **kwargs):
        raise RuntimeError(f"{self._name} is a stub: it is not on the forward path")

    def __mro_entries__(self, bases):
        return (object,)


class _StubModule(types.ModuleType):
    def __getattr__(self, item):
        if item.startswith("__"):
            raise AttributeError(item)
        return _Stub(f"{self.__name__}.{item}")


class _StubFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    def find_spec(self, fullname, path, target=None):
        if fullname.split(".")[0] in STUBBED:
            return importlib.machinery.ModuleSpec(fullname, self, is_package=True)
        return None

    def create_module(self, spec):
        m = _StubModule(spec.name)
        m.__path__ = []
        return m

    def exec_module(self, module):
        pass


def _torch_scatter():
    """`torch_scatter.segment_csr` through `torch.segment_reduce` (same reduction)."""
    m = types.ModuleType("torch_scatter")

    def segment_csr(src, indptr, reduce="sum", out=None):
        reduce = {"mean": "mean", "max": "max", "min": "min", "sum": "sum"}[reduce]
        return torch.segment_reduce(src, reduce, offsets=indptr, axis=0)

    m.segment_csr = segment_csr
    return m


RECORD = {"pooling_orders": [], "tome_destinations": [], "tome_grids": []}


def reset_record():
    for v in RECORD.values():
        v.clear()


def _record_pooling_orders():
    """Wraps `Point.serialization`: with `shuffle_orders`, replays the `torch.randperm` it is
    about to draw (global RNG state saved and restored) and checks the shuffled orders."""
    from core.models.encoders.sonata.structure import Point

    original = Point.serialization

    def serialization(self, order="z", depth=None, shuffle_orders=False):
        perm = None
        if shuffle_orders:
            state = torch.get_rng_state()
            perm = torch.randperm(len(order))
            torch.set_rng_state(state)
        original(self, order=order, depth=depth, shuffle_orders=shuffle_orders)
        if perm is not None:
            RECORD["pooling_orders"].append(perm.tolist())
            # mm_order is the unshuffled order[2]; it must now sit where perm points to 2.
            k = perm.tolist().index(2)
            assert torch.equal(self["serialized_order"][k], self["mm_order"]), "perm replay"

    Point.serialization = serialization


def _record_tome_draws():
    """Wraps the ToMe matcher the dense PIT calls: replays its `torch.randint` destination draw
    (generator state saved and restored)."""
    import core.models.transformer_block.efficient_pi_transformer_dense as pit

    original = pit.bipartite_soft_matching_random2d

    def matcher(metric, w, h, sx, sy, r, no_rand=False, generator=None):
        if r > 0 and not no_rand:
            state = generator.get_state()
            draw = torch.randint(
                sy * sx, size=(h // sy, w // sx, 1), device=generator.device, generator=generator
            )
            generator.set_state(state)
            RECORD["tome_destinations"].append(draw.reshape(-1).tolist())
            RECORD["tome_grids"].append((h, w))
        return original(metric, w, h, sx, sy, r, no_rand=no_rand, generator=generator)

    pit.bipartite_soft_matching_random2d = matcher


class FakeSkinning(torch.nn.Module):
    """Replaces the SMPL-X skinning module (licensed files, `.cuda()`): `get_query_points`
    returns the points, normals and part masks set with `set_inputs`."""

    def __init__(self, **kwargs):
        super().__init__()
        for k in ("is_rhand", "is_lhand", "is_upper_body", "is_constrain_body"):
            self.register_buffer(k, torch.zeros(1, dtype=torch.bool), persistent=False)
        self.inputs = None

    def set_inputs(self, coords, normals, masks):
        self.inputs = (coords, normals, masks)

    def get_query_points(self, query_pts_path, smplx_data, device):
        coords, normals, masks = self.inputs
        return dict(
            neutral_coords=coords[None],
            ori_neutral_coords=coords[None],
            neutral_normals=normals[None],
            transform_mat_to_null_pose=torch.eye(4).expand(1, 55, 4, 4),
            mesh_meta=dict(masks),
        )


def _fixture_dinov2(widths):
    """`dinov2_fixture14_reg`: the official DinoVisionTransformer with ViT-S/14-reg settings at
    `widths` = (embed_dim, depth, num_heads)."""
    from core.models.encoders.dinov2.hub import backbones
    from core.models.encoders.dinov2.models import vision_transformer as vits

    dim, depth, heads = widths

    def vit_fixture(patch_size=16, num_register_tokens=0, **kwargs):
        return vits.DinoVisionTransformer(
            patch_size=patch_size,
            embed_dim=dim,
            depth=depth,
            num_heads=heads,
            mlp_ratio=4,
            block_fn=partial(vits._block_cls(**kwargs), attn_class=vits.MemEffAttention),
            num_register_tokens=num_register_tokens,
            **kwargs,
        )

    vits.vit_fixture = vit_fixture

    def dinov2_fixture14_reg(*, pretrained=True, weights=backbones.Weights.LVD142M, **kwargs):
        return backbones._make_dinov2_model(
            arch_name="vit_fixture",
            pretrained=False,
            weights=weights,
            num_register_tokens=4,
            interpolate_antialias=True,
            interpolate_offset=0.0,
            **kwargs,
        )

    backbones.dinov2_fixture14_reg = dinov2_fixture14_reg


def _no_download_dinov2():
    """The DINOv2 wrapper always asks for pretrained weights (a download): build without."""
    from core.models.encoders import dinov2_wrapper

    build = dinov2_wrapper.Dinov2Wrapper._build_dinov2

    def _build_dinov2(model_name, modulation_dim=None, pretrained=True):
        return build(model_name, modulation_dim=modulation_dim, pretrained=False)

    dinov2_wrapper.Dinov2Wrapper._build_dinov2 = staticmethod(_build_dinov2)


def _fixture_dpt(features, out_channels):
    """`PatchDPT4DecoderOnly.build_decoder` builds `DPTHead(dim_in=1024 // depth)` with its
    default widths; for a small fixture the head reads `img_dim // depth` and the given widths."""
    from core.models.transformer_block import dpt_decoder

    head = dpt_decoder.DPTHead

    def build_decoder(self, img_dim=1024):
        mapping = {1: [0, 0, 0, 0], 4: [0, 1, 2, 3]}
        self.dense_predictor = head(
            dim_in=self.fixture_img_dim // self.depth,
            patch_size=self.enc_patch_size,
            intermediate_layer_idx=mapping[self.depth],
            features=features,
            out_channels=list(out_channels),
        )

    init = dpt_decoder.PatchDPT4DecoderOnly.__init__

    def __init__(self, enc_channels, img_dim, *args, **kwargs):
        # The parent constructor calls build_decoder: the width must be there before it.
        self.fixture_img_dim = img_dim
        init(self, enc_channels, img_dim, *args, **kwargs)

    dpt_decoder.PatchDPT4DecoderOnly.__init__ = __init__
    dpt_decoder.PatchDPT4DecoderOnly.build_decoder = build_decoder


def install(official_dir, dinov2_widths=None, dpt_widths=None):
    """Puts the official sources on the path with every shim; `dinov2_widths` (dim, depth,
    heads) registers `dinov2_fixture14_reg`, `dpt_widths` (features, out_channels) shrinks the
    DPT head of `PatchDPT4DecoderOnly`."""
    os.environ.setdefault("XFORMERS_DISABLED", "1")
    os.environ.setdefault("TORCHDYNAMO_DISABLE", "1")
    sys.meta_path.insert(0, _StubFinder())
    sys.modules["torch_scatter"] = _torch_scatter()
    sys.path.insert(0, str(official_dir))
    torch.cuda.synchronize = lambda *a, **k: None

    import accelerate

    accelerate.PartialState(cpu=True)

    from core.models.encoders.sonata.structure import Point

    Point.cuda = lambda self: None
    _record_pooling_orders()
    _record_tome_draws()
    _no_download_dinov2()
    if dinov2_widths is not None:
        _fixture_dinov2(dinov2_widths)
    if dpt_widths is not None:
        _fixture_dpt(*dpt_widths)

    import core.models.rendering.base_gs_render as base

    base.SMPLXDiffusedVoxelSkinning = FakeSkinning
    base.SMPLXVoxelSkinning = FakeSkinning


def spconv_single_thread():
    """spconv 2.3.8's CPU `SubMConv3d` gives wrong, run-dependent results with more than one
    torch thread: each call runs on one thread, the rest of the forward on the caller's count."""
    import spconv.pytorch as spconv

    forward = spconv.SubMConv3d.forward

    def single(self, *args, **kwargs):
        n = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            return forward(self, *args, **kwargs)
        finally:
            torch.set_num_threads(n)

    spconv.SubMConv3d.forward = single


def spconv_train_mode(model):
    """spconv's CPU kernel cannot add the bias in eval mode; in train mode it adds it in Python
    (the layer has no other train/eval difference)."""
    import spconv.pytorch as spconv

    for m in model.modules():
        if isinstance(m, spconv.SubMConv3d):
            m.train()
