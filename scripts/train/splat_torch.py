"""Differentiable Gaussian splatting in PyTorch on the CPU, for the training losses.

The same image model as our rasteriser (src/splat/render): EWA projection with a 0.3 px
low-pass, alpha = min(0.99, opacity * exp(power)), alpha < 1/255 skipped, front-to-back
compositing by depth, pixel centres at integer coordinates (ROS CameraInfo convention).

Instead of tiles it builds a list of (Gaussian, pixel) pairs inside each Gaussian's 3-sigma
box (at most `window`² pixels a Gaussian), sorts them by (pixel, depth) and composites with a
segmented exclusive cumulative sum of log(1 - alpha): cheap when Gaussians are a few pixels
wide, as they are at the training resolution.
"""

import torch

LOW_PASS = 0.3
ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.99


def quat_to_mat(q):
    """(w, x, y, z) quaternions [N, 4] (any norm) -> rotation matrices [N, 3, 3]."""
    q = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(-1, 3, 3)


def quat_mul(a, b):
    """Hamilton product of (w, x, y, z) quaternions [N, 4]."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        dim=-1,
    )


def render(means, quats, scales, opacities, colors, intrinsics, camera_from_world, size,
           background=1.0, window=9):
    """Renders N Gaussians (world frame) into a size x size camera.

    intrinsics: [4] fx, fy, cx, cy; camera_from_world: [3, 4]. Returns (rgb [3, H, W],
    alpha [H, W]); differentiable in every Gaussian attribute.
    """
    h = w = size
    fx, fy, cx, cy = intrinsics.unbind(0)
    rot_c, t_c = camera_from_world[:, :3], camera_from_world[:, 3]
    p = means @ rot_c.T + t_c
    keep = p[:, 2] > 0.05
    idx = keep.nonzero().squeeze(1)
    p = p[idx]
    x, y, z = p.unbind(-1)
    r = rot_c @ quat_to_mat(quats[idx])  # camera_from_gaussian rotation
    m = r * scales[idx].unsqueeze(1)  # R S
    cov_c = m @ m.transpose(1, 2)
    zero = torch.zeros_like(z)
    j = torch.stack(
        [fx / z, zero, -fx * x / (z * z), zero, fy / z, -fy * y / (z * z)], dim=-1
    ).reshape(-1, 2, 3)
    cov2 = j @ cov_c @ j.transpose(1, 2)
    a = cov2[:, 0, 0] + LOW_PASS
    b = cov2[:, 0, 1]
    c = cov2[:, 1, 1] + LOW_PASS
    det = (a * c - b * b).clamp_min(1e-12)
    ca, cb, cc = c / det, -b / det, a / det
    u = fx * x / z + cx
    v = fy * y / z + cy
    # Pairs: every pixel of a window around the rounded centre (no gradient through the choice).
    half = window // 2
    with torch.no_grad():
        off = torch.arange(-half, half + 1)
        oy, ox = torch.meshgrid(off, off, indexing="ij")
        px = (u.round().long()[:, None] + ox.reshape(1, -1))
        py = (v.round().long()[:, None] + oy.reshape(1, -1))
        inside = (px >= 0) & (px < w) & (py >= 0) & (py < h)
    g = torch.arange(idx.shape[0])[:, None].expand_as(px)[inside]
    px, py = px[inside], py[inside]
    dx = px.to(u.dtype) - u[g]
    dy = py.to(v.dtype) - v[g]
    power = -0.5 * (ca[g] * dx * dx + cc[g] * dy * dy) - cb[g] * dx * dy
    alpha = (opacities[idx].reshape(-1)[g] * torch.exp(power.clamp_max(0.0))).clamp_max(ALPHA_MAX)
    with torch.no_grad():
        live = (alpha >= ALPHA_MIN) & (power <= 0)
    g, px, py, alpha = g[live], px[live], py[live], alpha[live]
    pix = py * w + px
    with torch.no_grad():
        depth_rank = torch.argsort(torch.argsort(z))
        key = pix * idx.shape[0] + depth_rank[g]
        order = torch.argsort(key)
    g, pix, alpha = g[order], pix[order], alpha[order]
    log_t = torch.log1p(-alpha)
    csum = torch.cumsum(log_t, 0)
    with torch.no_grad():
        start = torch.ones_like(pix, dtype=torch.bool)
        start[1:] = pix[1:] != pix[:-1]
        seg = torch.cumsum(start.long(), 0) - 1
        first = start.nonzero().squeeze(1)
    # Exclusive sum within the pixel's segment: csum - log_t - (csum before the segment).
    seg_base = torch.where(first > 0, csum[(first - 1).clamp_min(0)], torch.zeros_like(csum[first]))[seg]
    trans = torch.exp(csum - log_t - seg_base)
    weight = alpha * trans
    col = colors[idx][g] * weight[:, None]
    rgb = torch.zeros(h * w, 3, dtype=means.dtype).index_add(0, pix, col)
    acc = torch.zeros(h * w, dtype=means.dtype).index_add(0, pix, weight)
    rgb = rgb + (1.0 - acc)[:, None] * background
    return rgb.T.reshape(3, h, w), acc.reshape(h, w)


def pose_gaussians(out, posed_anchors, posed_rotations):
    """Poses the network's canonical Gaussians like the node does (positions by the skinning
    of their anchor, rotations by its rotation): posed = skin(anchor) + R offset."""
    rot = quat_to_mat(posed_rotations)
    means = posed_anchors + (rot @ out["offsets"].unsqueeze(-1)).squeeze(-1)
    quats = quat_mul(posed_rotations, out["rotations"])
    return means, quats
