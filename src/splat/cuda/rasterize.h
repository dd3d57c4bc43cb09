// C interface of the CUDA splatting rasteriser (rasterize.cu). The same source builds for the GPU
// (nvcc, feature `cuda`) and for the CPU emulation that tests it without a GPU (emulate.h).
// Mirrored in Rust by src/splat/cuda/params.rs: keep both in step.
#ifndef LHMPP_SPLAT_RASTERIZE_H
#define LHMPP_SPLAT_RASTERIZE_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

// Camera, image and options of one frame (all plain values).
typedef struct {
  float view[12];           // world -> optical frame, 3x4 row-major [R | t]
  float center[3];          // camera centre in the world
  float fx, fy, cx, cy;     // pinhole intrinsics (pixels)
  int32_t width, height;    // image size (pixels)
  float near_plane, far_plane;
  float low_pass;           // added to the 2D covariance diagonal (pixels^2)
  float background[3];      // colour behind the Gaussians
  int32_t sh_degree;        // 0..3
  int32_t channels;         // feature channels to render (0 = none)
  int32_t num_gaussians;
} LhmppSplatParams;

// The Gaussians, in device memory (host memory under emulation), struct of arrays.
typedef struct {
  const float* positions;            // N x 3
  const float* scales;               // N x 3 (linear standard deviations)
  const float* rotations;            // N x 4 (x, y, z, w; need not be unit)
  const float* opacities;            // N
  const float* sh;                   // N x (sh_degree + 1)^2 x 3
  const float* features;             // N x channels (NULL when channels = 0)
  const float* background_features;  // channels (NULL when channels = 0)
} LhmppSplatScene;

// The output maps, in device memory, row-major, top row first.
typedef struct {
  float* rgb;       // H x W x 3
  float* alpha;     // H x W
  float* depth;     // H x W
  float* features;  // H x W x channels (NULL when channels = 0)
} LhmppSplatImage;

// Work sizes of one frame.
typedef struct {
  uint32_t visible;     // Gaussians that survived culling
  uint32_t tile_pairs;  // (tile, Gaussian) pairs blended
} LhmppSplatStats;

// Grow-only scratch buffers kept between frames (opaque).
void* lhmpp_splat_workspace_new(void);
void lhmpp_splat_workspace_free(void* workspace);

// Renders one frame on `stream` (a cudaStream_t). Returns 0, or a CUDA error code (see
// lhmpp_splat_error_string). Waits once mid-frame for the number of (tile, Gaussian) pairs; the
// blend is left queued on the stream.
int32_t lhmpp_splat_render(void* workspace, const LhmppSplatParams* params,
                           const LhmppSplatScene* scene, const LhmppSplatImage* image,
                           LhmppSplatStats* stats, void* stream);

// Text of an error code returned by lhmpp_splat_render.
const char* lhmpp_splat_error_string(int32_t code);

#ifdef __cplusplus
}
#endif

#endif
