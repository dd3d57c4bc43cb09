//! Gaussian avatars' rendering side: the Gaussian set, the camera, the CPU splatting
//! rasteriser, its CUDA twin ([`cuda`]), 3DGS-layout PLY import/export and SPZ ([`write_spz`]). Synchronous.

mod camera;
pub mod cuda;
mod gaussians;
mod nearest;
mod ply;
pub mod render;
mod sh;
mod spz;
pub mod synthetic;
mod voxel_skinning;

pub use camera::{Camera, Intrinsics};
pub use gaussians::{
    rgb_to_sh_dc, sh_coeff_count, sh_dc_to_rgb, GaussianError, Gaussians, MAX_SH_DEGREE, SH_C0,
};
pub use nearest::nearest_vertex_skin;
pub use ply::{read_ply, read_ply_from, write_ply, write_ply_to, PlyError, PlyGaussians};
pub use render::{
    blend_instruction_set, render, render_timed, RasterStageTimes, Rasterizer, RenderOptions,
    RenderOutput, TILE,
};
pub use sh::eval_sh;
pub use spz::{
    pack_rotation, read_spz, unpack_rotation, write_spz, SpzError, SpzQuantised,
    DEFAULT_FRACTIONAL_BITS, MAX_SPZ_GAUSSIANS,
};
pub use voxel_skinning::{VoxelSkinning, VoxelSkinningError};
