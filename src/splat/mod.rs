//! Gaussian avatars: the Gaussian set, linear-blend-skinning animation, the splatting
//! rasteriser (CPU; CUDA behind the `cuda` feature) and 3DGS-layout PLY import/export.
