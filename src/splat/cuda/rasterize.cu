// CUDA splatting rasteriser: the stages of the Rust CPU rasteriser (src/splat/render/) as GPU
// kernels, with the same arithmetic and the same tie rules, so that both give the same image
// up to floating-point rounding (fused multiply-adds, expf).
//
//   project      one thread per Gaussian: EWA projection, SH colour, culling, tile rectangle
//   compact      visible Gaussians -> (depth bits, index), in index order
//   radix sort   stable LSD sort by depth (4 passes of 8 bits): front-to-back order
//   count/emit   (tile, Gaussian) pairs in depth order, row-major tiles within a Gaussian
//   radix sort   stable sort of the pairs by tile: every tile's list stays front to back
//   ranges       first and last pair of each tile
//   blend        one 256-thread block per 16x16 tile, one thread per pixel; splats staged
//                through shared memory 256 at a time; the block stops once all pixels are done;
//                feature channels 32 per launch, accumulated in registers
//
// The host code below runs the stages on one stream. It builds with nvcc for the GPU, and with
// a plain C++20 compiler and emulate.h for the CPU emulation the tests run without a GPU.

#include "rasterize.h"

#ifdef __CUDACC__
#include <cuda_runtime.h>
#define LAUNCH(kernel, blocks, threads, stream, ...) \
  kernel<<<(blocks), (threads), 0, (stream)>>>(__VA_ARGS__)
#else
#include "emulate.h"
#endif

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

namespace {

constexpr int TILE = 16;
constexpr int BLOCK = 256;  // threads per block; also the radix (8-bit digits)
constexpr float MIN_ALPHA = 1.0f / 255.0f;
constexpr float MAX_ALPHA = 0.99f;
constexpr float MIN_TRANSMITTANCE = 1e-4f;
constexpr uint32_t SCAN_PER_THREAD = 4;
constexpr uint32_t SCAN_BLOCK = BLOCK * SCAN_PER_THREAD;
constexpr int FEATURE_CHUNK = 32;  // feature channels blended per launch (registers)
constexpr uint32_t SORT_PER_BLOCK = BLOCK * 4;  // items per radix-sort block: many blocks in flight

// A Gaussian as the camera sees it (what the blend reads).
struct Splat {
  float mx, my;           // centre (pixels)
  float ca, cb, cc;       // conic: inverse 2D covariance [a b; b c]
  float opacity;          // (1/255, 1]
  float min_power;        // ln(1/255 / opacity): lower powers give alpha < 1/255
  float depth;            // optical-frame z
  float r, g, b;          // view-dependent colour
  uint32_t index;         // source Gaussian (its feature row)
};

// Tiles [x0, x1) x [y0, y1) a splat reaches.
struct Rect {
  int32_t x0, x1, y0, y1;
};

__device__ __forceinline__ bool is_finite(float x) { return fabsf(x) <= 3.402823466e38f; }

__device__ __forceinline__ float clampf(float v, float lo, float hi) {
  return fminf(fmaxf(v, lo), hi);
}

__device__ __forceinline__ uint32_t float_bits(float v) {
  uint32_t bits;
  memcpy(&bits, &v, sizeof bits);
  return bits;
}

// 3DGS real spherical harmonics, degree 0..3 (same basis, signs and clamp as src/splat/sh.rs).
__device__ void eval_sh(int degree, const float* sh, float x, float y, float z, float* rgb) {
  const float C0 = 0.2820948f, C1 = 0.4886025f;
  const float C2[5] = {1.0925484f, -1.0925484f, 0.31539157f, -1.0925484f, 0.5462742f};
  const float C3[7] = {-0.5900436f, 2.8906114f, -0.4570458f, 0.37317633f,
                       -0.4570458f, 1.4453057f, -0.5900436f};
  float basis[16];
  basis[0] = C0;
  int count = 1;
  if (degree > 0) {
    basis[1] = -C1 * y;
    basis[2] = C1 * z;
    basis[3] = -C1 * x;
    count = 4;
    if (degree > 1) {
      float xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
      basis[4] = C2[0] * xy;
      basis[5] = C2[1] * yz;
      basis[6] = C2[2] * (2.0f * zz - xx - yy);
      basis[7] = C2[3] * xz;
      basis[8] = C2[4] * (xx - yy);
      count = 9;
      if (degree > 2) {
        basis[9] = C3[0] * y * (3.0f * xx - yy);
        basis[10] = C3[1] * xy * z;
        basis[11] = C3[2] * y * (4.0f * zz - xx - yy);
        basis[12] = C3[3] * z * (2.0f * zz - 3.0f * xx - 3.0f * yy);
        basis[13] = C3[4] * x * (4.0f * zz - xx - yy);
        basis[14] = C3[5] * z * (xx - yy);
        basis[15] = C3[6] * x * (xx - 3.0f * yy);
        count = 16;
      }
    }
  }
  for (int c = 0; c < 3; ++c) {
    float sum = 0.0f;
    for (int k = 0; k < count; ++k) sum += basis[k] * sh[3 * k + c];
    rgb[c] = fmaxf(sum + 0.5f, 0.0f);
  }
}

// Stage 1: one thread per Gaussian. Mirrors src/splat/render/project.rs and the contributing
// rectangle of bin.rs; culled Gaussians get visible = 0.
__global__ void project_kernel(LhmppSplatParams p, LhmppSplatScene s, Splat* splats, Rect* rects,
                               uint32_t* visible, uint32_t* depth_bits) {
  uint32_t i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= (uint32_t)p.num_gaussians) return;
  visible[i] = 0;
  float opacity = s.opacities[i];
  if (!(opacity >= MIN_ALPHA)) return;  // also NaN
  opacity = fminf(opacity, 1.0f);
  const float* pos = s.positions + 3 * (size_t)i;
  const float* v = p.view;
  float px = v[0] * pos[0] + v[1] * pos[1] + v[2] * pos[2] + v[3];
  float py = v[4] * pos[0] + v[5] * pos[1] + v[6] * pos[2] + v[7];
  float pz = v[8] * pos[0] + v[9] * pos[1] + v[10] * pos[2] + v[11];
  if (!(pz > p.near_plane && pz < p.far_plane)) return;
  const float* sc = s.scales + 3 * (size_t)i;
  const float* q = s.rotations + 4 * (size_t)i;
  float qlen = sqrtf(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  if (!(qlen > 1e-12f)) return;
  for (int k = 0; k < 3; ++k)
    if (!is_finite(sc[k]) || !is_finite(pos[k])) return;
  float qx = q[0] / qlen, qy = q[1] / qlen, qz = q[2] / qlen, qw = q[3] / qlen;
  // Rotation matrix (row r, column c) of the unit quaternion, columns scaled: M = R diag(s).
  float x2 = qx + qx, y2 = qy + qy, z2 = qz + qz;
  float xx = qx * x2, xy = qx * y2, xz = qx * z2, yy = qy * y2, yz = qy * z2, zz = qz * z2;
  float wx = qw * x2, wy = qw * y2, wz = qw * z2;
  float m[3][3] = {{(1.0f - (yy + zz)) * sc[0], (xy - wz) * sc[1], (xz + wy) * sc[2]},
                   {(xy + wz) * sc[0], (1.0f - (xx + zz)) * sc[1], (yz - wx) * sc[2]},
                   {(xz - wy) * sc[0], (yz + wx) * sc[1], (1.0f - (xx + yy)) * sc[2]}};
  // Camera-frame covariance W (M M^T) W^T, through WM = W M.
  float wm[3][3];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      wm[r][c] = v[4 * r] * m[0][c] + v[4 * r + 1] * m[1][c] + v[4 * r + 2] * m[2][c];
  float cov[3][3];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      cov[r][c] = wm[r][0] * wm[c][0] + wm[r][1] * wm[c][1] + wm[r][2] * wm[c][2];

  float w = (float)p.width, h = (float)p.height;
  float lim_x_pos = (w - p.cx) / p.fx + 0.3f * w / p.fx;
  float lim_x_neg = p.cx / p.fx + 0.3f * w / p.fx;
  float lim_y_pos = (h - p.cy) / p.fy + 0.3f * h / p.fy;
  float lim_y_neg = p.cy / p.fy + 0.3f * h / p.fy;
  float inv_z = 1.0f / pz;
  float tx = pz * clampf(px * inv_z, -lim_x_neg, lim_x_pos);
  float ty = pz * clampf(py * inv_z, -lim_y_neg, lim_y_pos);
  float j0[3] = {p.fx * inv_z, 0.0f, -p.fx * tx * inv_z * inv_z};
  float j1[3] = {0.0f, p.fy * inv_z, -p.fy * ty * inv_z * inv_z};
  float sj0[3], sj1[3];
  for (int r = 0; r < 3; ++r) {
    sj0[r] = cov[r][0] * j0[0] + cov[r][1] * j0[1] + cov[r][2] * j0[2];
    sj1[r] = cov[r][0] * j1[0] + cov[r][1] * j1[1] + cov[r][2] * j1[2];
  }
  float a = j0[0] * sj0[0] + j0[1] * sj0[1] + j0[2] * sj0[2] + p.low_pass;
  float b = j1[0] * sj0[0] + j1[1] * sj0[1] + j1[2] * sj0[2];
  float c = j1[0] * sj1[0] + j1[1] * sj1[1] + j1[2] * sj1[2] + p.low_pass;
  float det = a * c - b * b;
  if (!(det > 0.0f) || !is_finite(det)) return;
  float inv_det = 1.0f / det;
  float ca = c * inv_det, cb = -b * inv_det, cc = a * inv_det;
  if (!is_finite(ca) || !is_finite(cb) || !is_finite(cc)) return;
  float mid = 0.5f * (a + c);
  float lambda = mid + sqrtf(fmaxf(mid * mid - det, 0.1f));
  float radius = ceilf(3.0f * sqrtf(lambda));
  float mx = p.fx * px * inv_z + p.cx, my = p.fy * py * inv_z + p.cy;
  if (!is_finite(radius) || !is_finite(mx) || !is_finite(my)) return;
  if (mx + radius < -0.5f || mx - radius > w - 0.5f || my + radius < -0.5f ||
      my - radius > h - 0.5f)
    return;
  float min_power = logf(MIN_ALPHA / opacity);
  float t = 2.0f * logf(opacity / MIN_ALPHA);
  float ext_x = sqrtf(t * a) + 0.5f, ext_y = sqrtf(t * c) + 0.5f;

  float dx = pos[0] - p.center[0], dy = pos[1] - p.center[1], dz = pos[2] - p.center[2];
  float len = sqrtf(dx * dx + dy * dy + dz * dz);
  float rcp = 1.0f / len;
  if (!(is_finite(rcp) && rcp > 0.0f)) rcp = 0.0f;  // glam's normalize_or_zero
  int k_sh = (p.sh_degree + 1) * (p.sh_degree + 1);
  float rgb[3];
  eval_sh(p.sh_degree, s.sh + (size_t)i * k_sh * 3, dx * rcp, dy * rcp, dz * rcp, rgb);
  if (!is_finite(rgb[0]) || !is_finite(rgb[1]) || !is_finite(rgb[2])) return;
  for (int k = 0; k < p.channels; ++k)
    if (!is_finite(s.features[(size_t)i * p.channels + k])) return;

  int cols = (p.width + TILE - 1) / TILE, rows = (p.height + TILE - 1) / TILE;
  float hx = fminf(radius, ext_x), hy = fminf(radius, ext_y);
  Rect rect;
  rect.x0 = (int32_t)clampf(floorf((mx - hx) / TILE), 0.0f, (float)cols);
  rect.x1 = (int32_t)clampf(floorf((mx + hx) / TILE) + 1.0f, 0.0f, (float)cols);
  rect.y0 = (int32_t)clampf(floorf((my - hy) / TILE), 0.0f, (float)rows);
  rect.y1 = (int32_t)clampf(floorf((my + hy) / TILE) + 1.0f, 0.0f, (float)rows);
  Splat out = {mx, my, ca, cb, cc, opacity, min_power, pz, rgb[0], rgb[1], rgb[2], i};
  splats[i] = out;
  rects[i] = rect;
  depth_bits[i] = float_bits(pz);
  visible[i] = 1;
}

// Exclusive scan, step 1: each block scans SCAN_BLOCK values and writes its total.
__global__ void scan_blocks_kernel(const uint32_t* in, uint32_t* out, uint32_t n,
                                   uint32_t* block_sums) {
  __shared__ uint32_t sums[BLOCK];
  uint32_t first = blockIdx.x * SCAN_BLOCK + threadIdx.x * SCAN_PER_THREAD;
  uint32_t values[SCAN_PER_THREAD];
  uint32_t total = 0;
  for (uint32_t q = 0; q < SCAN_PER_THREAD; ++q) {
    values[q] = first + q < n ? in[first + q] : 0;
    total += values[q];
  }
  sums[threadIdx.x] = total;
  __syncthreads();
  for (uint32_t offset = 1; offset < BLOCK; offset <<= 1) {
    uint32_t add = threadIdx.x >= offset ? sums[threadIdx.x - offset] : 0;
    __syncthreads();
    sums[threadIdx.x] += add;
    __syncthreads();
  }
  uint32_t running = threadIdx.x > 0 ? sums[threadIdx.x - 1] : 0;
  for (uint32_t q = 0; q < SCAN_PER_THREAD; ++q) {
    if (first + q < n) out[first + q] = running;
    running += values[q];
  }
  if (threadIdx.x == BLOCK - 1) block_sums[blockIdx.x] = sums[BLOCK - 1];
}

// Exclusive scan, step 2: add each block's offset.
__global__ void scan_add_kernel(uint32_t* out, uint32_t n, const uint32_t* block_offsets) {
  uint32_t i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i < n) out[i] += block_offsets[i / SCAN_BLOCK];
}

// The scan's grand total: last exclusive value + last input.
__global__ void scan_total_kernel(const uint32_t* in, const uint32_t* out, uint32_t n,
                                  uint32_t* total) {
  if (blockIdx.x == 0 && threadIdx.x == 0) *total = n ? out[n - 1] + in[n - 1] : 0;
}

// Visible Gaussians -> (depth bits, index), in index order.
__global__ void compact_kernel(const uint32_t* visible, const uint32_t* offsets,
                               const uint32_t* depth_bits, uint32_t n, uint32_t* keys,
                               uint32_t* values) {
  uint32_t i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= n || !visible[i]) return;
  keys[offsets[i]] = depth_bits[i];
  values[offsets[i]] = i;
}

// Radix sort pass, step 1: per-block digit counts, digit-major (counts[digit * blocks + block]),
// so that one exclusive scan gives every (digit, block) its first output slot.
__global__ void radix_count_kernel(const uint32_t* keys, uint32_t n, int shift,
                                   uint32_t* counts) {
  __shared__ uint32_t histogram[BLOCK];
  histogram[threadIdx.x] = 0;
  __syncthreads();
  uint32_t begin = blockIdx.x * SORT_PER_BLOCK;
  uint32_t end = begin + SORT_PER_BLOCK < n ? begin + SORT_PER_BLOCK : n;
  for (uint32_t k = begin + threadIdx.x; k < end; k += BLOCK)
    atomicAdd(&histogram[(keys[k] >> shift) & 0xff], 1u);
  __syncthreads();
  counts[threadIdx.x * gridDim.x + blockIdx.x] = histogram[threadIdx.x];
}

// Radix sort pass, step 2: stable scatter. The block walks its items 256 at a time in order;
// an item's rank is the number of earlier items of the chunk with the same digit.
__global__ void radix_scatter_kernel(const uint32_t* keys, const uint32_t* values, uint32_t n,
                                     int shift, const uint32_t* offsets, uint32_t* keys_out,
                                     uint32_t* values_out) {
  __shared__ uint32_t base[BLOCK];
  __shared__ uint32_t digits[BLOCK];
  base[threadIdx.x] = offsets[threadIdx.x * gridDim.x + blockIdx.x];
  uint32_t begin = blockIdx.x * SORT_PER_BLOCK;
  uint32_t end = begin + SORT_PER_BLOCK < n ? begin + SORT_PER_BLOCK : n;
  for (uint32_t chunk = begin; chunk < end; chunk += BLOCK) {
    uint32_t k = chunk + threadIdx.x;
    bool has = k < end;
    uint32_t key = has ? keys[k] : 0;
    uint32_t digit = has ? (key >> shift) & 0xff : BLOCK;  // BLOCK: matches no digit
    digits[threadIdx.x] = digit;
    __syncthreads();
    if (has) {
      uint32_t rank = 0;
      for (uint32_t j = 0; j < threadIdx.x; ++j) rank += digits[j] == digit;
      uint32_t slot = base[digit] + rank;
      keys_out[slot] = key;
      values_out[slot] = values[k];
    }
    uint32_t mine = 0;  // items of this chunk with digit == threadIdx.x
    for (uint32_t j = 0; j < BLOCK; ++j) mine += digits[j] == threadIdx.x;
    __syncthreads();
    base[threadIdx.x] += mine;
  }
}

// Number of tiles each depth-ordered splat reaches.
__global__ void tile_count_kernel(const uint32_t* order, const Rect* rects, uint32_t m,
                                  uint32_t* counts) {
  uint32_t k = blockIdx.x * blockDim.x + threadIdx.x;
  if (k >= m) return;
  Rect r = rects[order[k]];
  counts[k] = (uint32_t)((r.x1 - r.x0) * (r.y1 - r.y0));
}

// (tile, splat) pairs: splats in depth order, each one's tiles row by row.
__global__ void emit_pairs_kernel(const uint32_t* order, const Rect* rects,
                                  const uint32_t* offsets, uint32_t m, int cols,
                                  uint32_t* tile_keys, uint32_t* splat_values) {
  uint32_t k = blockIdx.x * blockDim.x + threadIdx.x;
  if (k >= m) return;
  uint32_t i = order[k];
  Rect r = rects[i];
  uint32_t slot = offsets[k];
  for (int ty = r.y0; ty < r.y1; ++ty)
    for (int tx = r.x0; tx < r.x1; ++tx) {
      tile_keys[slot] = (uint32_t)(ty * cols + tx);
      splat_values[slot] = i;
      ++slot;
    }
}

// ranges[2t], ranges[2t + 1]: the pairs of tile t (zeroed beforehand for empty tiles).
__global__ void tile_ranges_kernel(const uint32_t* tile_keys, uint32_t pairs, uint32_t* ranges) {
  uint32_t k = blockIdx.x * blockDim.x + threadIdx.x;
  if (k >= pairs) return;
  uint32_t tile = tile_keys[k];
  if (k == 0 || tile_keys[k - 1] != tile) ranges[2 * tile] = k;
  if (k + 1 == pairs || tile_keys[k + 1] != tile) ranges[2 * tile + 1] = k + 1;
}

// Stage 4: front-to-back compositing (3DGS semantics, see src/splat/render/blend.rs). One block
// per tile, one thread per pixel, splats staged through shared memory 256 at a time. Feature
// channels are blended CHUNK at a time (one launch per chunk, accumulated in registers from
// features staged in shared memory); the launch of chunk 0 (or the only launch, CHUNK = 0, when
// there are no features) also writes colour, alpha and depth. Every launch repeats the same
// transmittance sequence, so all chunks stop at the same samples.
template <int CHUNK>
__global__ void blend_kernel(LhmppSplatParams p, const Splat* splats, const uint32_t* tile_splats,
                             const uint32_t* ranges, const float* features,
                             const float* background_features, LhmppSplatImage out,
                             int channel_offset) {
  __shared__ Splat batch[BLOCK];
  __shared__ float batch_features[CHUNK > 0 ? BLOCK * CHUNK : 1];
  int cols = (p.width + TILE - 1) / TILE;
  int tile = blockIdx.x;
  int x = (tile % cols) * TILE + (int)(threadIdx.x % TILE);
  int y = (tile / cols) * TILE + (int)(threadIdx.x / TILE);
  bool inside = x < p.width && y < p.height;
  float fx = (float)x, fy = (float)y;
  int channels = p.channels;
  int chunk = CHUNK > 0 ? (channels - channel_offset < CHUNK ? channels - channel_offset : CHUNK) : 0;
  float acc[CHUNK > 0 ? CHUNK : 1];
  for (int k = 0; k < CHUNK; ++k) acc[k] = 0.0f;
  float transmittance = 1.0f, r = 0.0f, g = 0.0f, b = 0.0f, depth = 0.0f;
  bool live = inside;
  uint32_t start = ranges[2 * tile], end = ranges[2 * tile + 1];
  for (uint32_t first = start; first < end; first += BLOCK) {
    // Also the barrier between the previous batch's reads and this batch's writes.
    if (__syncthreads_count(!live) == BLOCK) break;
    if (first + threadIdx.x < end) {
      uint32_t i = tile_splats[first + threadIdx.x];
      batch[threadIdx.x] = splats[i];
      const float* f = features + (size_t)i * channels + channel_offset;
      for (int k = 0; k < CHUNK; ++k)
        if (k < chunk) batch_features[threadIdx.x * CHUNK + k] = f[k];
    }
    __syncthreads();
    uint32_t count = end - first < (uint32_t)BLOCK ? end - first : (uint32_t)BLOCK;
    for (uint32_t j = 0; live && j < count; ++j) {
      const Splat& s = batch[j];
      float dx = s.mx - fx, dy = s.my - fy;
      float power = -0.5f * (s.ca * dx * dx + s.cc * dy * dy) - s.cb * dx * dy;
      if (power > 0.0f || power < s.min_power) continue;
      float alpha = fminf(MAX_ALPHA, s.opacity * expf(power));
      if (alpha < MIN_ALPHA) continue;
      float next = transmittance * (1.0f - alpha);
      if (next < MIN_TRANSMITTANCE) {
        live = false;
        break;
      }
      float weight = alpha * transmittance;
      r += s.r * weight;
      g += s.g * weight;
      b += s.b * weight;
      depth += s.depth * weight;
      for (int k = 0; k < CHUNK; ++k)
        if (k < chunk) acc[k] += batch_features[j * CHUNK + k] * weight;
      transmittance = next;
    }
  }
  if (!inside) return;
  size_t pixel = (size_t)y * p.width + x;
  if (channel_offset == 0) {
    out.rgb[3 * pixel] = r + transmittance * p.background[0];
    out.rgb[3 * pixel + 1] = g + transmittance * p.background[1];
    out.rgb[3 * pixel + 2] = b + transmittance * p.background[2];
    float a = 1.0f - transmittance;
    out.alpha[pixel] = a;
    out.depth[pixel] = a > 0.0f ? depth / a : 0.0f;
  }
  float* feat = out.features + pixel * channels + channel_offset;
  for (int k = 0; k < CHUNK; ++k)
    if (k < chunk) feat[k] = acc[k] + transmittance * background_features[channel_offset + k];
}

// A grow-only device buffer.
struct Buffer {
  void* ptr = nullptr;
  size_t bytes = 0;
};

// Scratch buffers kept between frames.
struct Workspace {
  Buffer splats, rects, visible, visible_offsets, depth_bits;
  Buffer keys[2], values[2];           // depth sort ping-pong (visible Gaussians)
  Buffer tile_counts, pair_offsets;     // per visible Gaussian
  Buffer pair_keys[2], pair_values[2];  // tile sort ping-pong (pairs)
  Buffer radix_counts, radix_offsets;
  Buffer ranges, total;
  Buffer scan_sums[8], scan_offsets[8];  // one per recursion level of the scan
};

uint32_t blocks_for(uint32_t n, uint32_t per_block) { return (n + per_block - 1) / per_block; }

// Makes `b` hold at least `bytes` (contents are lost when it grows). Growing first waits for
// `stream`: the previous frame's blend may still be reading the old buffer.
cudaError_t reserve(Buffer& b, size_t bytes, cudaStream_t stream) {
  if (bytes <= b.bytes) return cudaSuccess;
  if (b.ptr) {
    cudaError_t e = cudaStreamSynchronize(stream);
    if (e != cudaSuccess) return e;
    e = cudaFree(b.ptr);
    if (e != cudaSuccess) return e;
    b.ptr = nullptr;
    b.bytes = 0;
  }
  size_t grown = bytes + bytes / 4 + 256;
  cudaError_t e = cudaMalloc(&b.ptr, grown);
  if (e == cudaSuccess) b.bytes = grown;
  return e;
}

template <class T>
T* as(Buffer& b) {
  return static_cast<T*>(b.ptr);
}

#define TRY(expr)                         \
  do {                                    \
    cudaError_t e_ = (expr);              \
    if (e_ != cudaSuccess) return (int32_t)e_; \
  } while (0)

// Exclusive scan of n values (in != out); recursion level `level` uses the level's buffers.
int32_t exclusive_scan(Workspace& ws, const uint32_t* in, uint32_t* out, uint32_t n, int level,
                       cudaStream_t stream) {
  if (n == 0) return 0;
  if (level >= 8) return (int32_t)cudaErrorMemoryAllocation;  // 1024^8 values: never
  uint32_t blocks = blocks_for(n, SCAN_BLOCK);
  TRY(reserve(ws.scan_sums[level], blocks * sizeof(uint32_t), stream));
  TRY(reserve(ws.scan_offsets[level], blocks * sizeof(uint32_t), stream));
  uint32_t* sums = as<uint32_t>(ws.scan_sums[level]);
  LAUNCH(scan_blocks_kernel, blocks, BLOCK, stream, in, out, n, sums);
  TRY(cudaGetLastError());
  if (blocks > 1) {
    uint32_t* offsets = as<uint32_t>(ws.scan_offsets[level]);
    int32_t e = exclusive_scan(ws, sums, offsets, blocks, level + 1, stream);
    if (e) return e;
    LAUNCH(scan_add_kernel, blocks_for(n, BLOCK), BLOCK, stream, out, n, (const uint32_t*)offsets);
    TRY(cudaGetLastError());
  }
  return 0;
}

// The total of the values just scanned, copied to the host (waits for the stream).
int32_t scan_total(Workspace& ws, const uint32_t* in, const uint32_t* out, uint32_t n,
                   cudaStream_t stream, uint32_t* total) {
  TRY(reserve(ws.total, sizeof(uint32_t), stream));
  LAUNCH(scan_total_kernel, 1, 1, stream, in, out, n, as<uint32_t>(ws.total));
  TRY(cudaGetLastError());
  TRY(cudaMemcpyAsync(total, ws.total.ptr, sizeof(uint32_t), cudaMemcpyDeviceToHost, stream));
  TRY(cudaStreamSynchronize(stream));
  return 0;
}

// Stable sort of n (key, value) pairs by the low `bits` bits of the key, 8 bits per pass.
// Returns which of the two ping-pong buffers holds the result through `result`.
int32_t radix_sort(Workspace& ws, Buffer* keys, Buffer* values, uint32_t n, int bits,
                   cudaStream_t stream, int* result) {
  int cur = 0;
  *result = 0;
  if (n <= 1) return 0;
  uint32_t blocks = blocks_for(n, SORT_PER_BLOCK);
  TRY(reserve(ws.radix_counts, (size_t)BLOCK * blocks * sizeof(uint32_t), stream));
  TRY(reserve(ws.radix_offsets, (size_t)BLOCK * blocks * sizeof(uint32_t), stream));
  uint32_t* counts = as<uint32_t>(ws.radix_counts);
  uint32_t* offsets = as<uint32_t>(ws.radix_offsets);
  for (int shift = 0; shift < bits; shift += 8) {
    LAUNCH(radix_count_kernel, blocks, BLOCK, stream, (const uint32_t*)as<uint32_t>(keys[cur]), n,
           shift, counts);
    TRY(cudaGetLastError());
    int32_t e = exclusive_scan(ws, counts, offsets, BLOCK * blocks, 0, stream);
    if (e) return e;
    LAUNCH(radix_scatter_kernel, blocks, BLOCK, stream, (const uint32_t*)as<uint32_t>(keys[cur]),
           (const uint32_t*)as<uint32_t>(values[cur]), n, shift, (const uint32_t*)offsets,
           as<uint32_t>(keys[1 - cur]), as<uint32_t>(values[1 - cur]));
    TRY(cudaGetLastError());
    cur = 1 - cur;
  }
  *result = cur;
  return 0;
}

int bits_for(uint32_t values) {
  int bits = 0;
  while (bits < 32 && (1ull << bits) < values) ++bits;
  return bits;
}

int32_t render(Workspace& ws, const LhmppSplatParams& p, const LhmppSplatScene& scene,
               const LhmppSplatImage& image, LhmppSplatStats* stats, cudaStream_t stream) {
  stats->visible = 0;
  stats->tile_pairs = 0;
  if (p.width <= 0 || p.height <= 0) return 0;
  uint32_t n = p.num_gaussians > 0 ? (uint32_t)p.num_gaussians : 0;
  uint32_t cols = blocks_for(p.width, TILE), rows = blocks_for(p.height, TILE);
  uint32_t tiles = cols * rows;
  TRY(reserve(ws.ranges, 2 * (size_t)tiles * sizeof(uint32_t), stream));
  TRY(cudaMemsetAsync(ws.ranges.ptr, 0, 2 * (size_t)tiles * sizeof(uint32_t), stream));
  uint32_t m = 0, pairs = 0;
  int tile_buf = 0;
  if (n > 0) {
    TRY(reserve(ws.splats, n * sizeof(Splat), stream));
    TRY(reserve(ws.rects, n * sizeof(Rect), stream));
    TRY(reserve(ws.visible, n * sizeof(uint32_t), stream));
    TRY(reserve(ws.visible_offsets, n * sizeof(uint32_t), stream));
    TRY(reserve(ws.depth_bits, n * sizeof(uint32_t), stream));
    Splat* splats = as<Splat>(ws.splats);
    Rect* rects = as<Rect>(ws.rects);
    uint32_t* visible = as<uint32_t>(ws.visible);
    LAUNCH(project_kernel, blocks_for(n, BLOCK), BLOCK, stream, p, scene, splats, rects, visible,
           as<uint32_t>(ws.depth_bits));
    TRY(cudaGetLastError());
    int32_t e = exclusive_scan(ws, visible, as<uint32_t>(ws.visible_offsets), n, 0, stream);
    if (e) return e;
    e = scan_total(ws, visible, as<uint32_t>(ws.visible_offsets), n, stream, &m);
    if (e) return e;
  }
  if (m > 0) {
    for (int k = 0; k < 2; ++k) {
      TRY(reserve(ws.keys[k], m * sizeof(uint32_t), stream));
      TRY(reserve(ws.values[k], m * sizeof(uint32_t), stream));
    }
    LAUNCH(compact_kernel, blocks_for(n, BLOCK), BLOCK, stream,
           (const uint32_t*)as<uint32_t>(ws.visible),
           (const uint32_t*)as<uint32_t>(ws.visible_offsets),
           (const uint32_t*)as<uint32_t>(ws.depth_bits), n, as<uint32_t>(ws.keys[0]),
           as<uint32_t>(ws.values[0]));
    TRY(cudaGetLastError());
    int sorted = 0;
    int32_t e = radix_sort(ws, ws.keys, ws.values, m, 32, stream, &sorted);
    if (e) return e;
    const uint32_t* order = as<uint32_t>(ws.values[sorted]);
    TRY(reserve(ws.tile_counts, m * sizeof(uint32_t), stream));
    TRY(reserve(ws.pair_offsets, m * sizeof(uint32_t), stream));
    uint32_t* counts = as<uint32_t>(ws.tile_counts);
    LAUNCH(tile_count_kernel, blocks_for(m, BLOCK), BLOCK, stream, order,
           (const Rect*)as<Rect>(ws.rects), m, counts);
    TRY(cudaGetLastError());
    e = exclusive_scan(ws, counts, as<uint32_t>(ws.pair_offsets), m, 0, stream);
    if (e) return e;
    e = scan_total(ws, counts, as<uint32_t>(ws.pair_offsets), m, stream, &pairs);
    if (e) return e;
    if (pairs > 0) {
      for (int k = 0; k < 2; ++k) {
        TRY(reserve(ws.pair_keys[k], pairs * sizeof(uint32_t), stream));
        TRY(reserve(ws.pair_values[k], pairs * sizeof(uint32_t), stream));
      }
      LAUNCH(emit_pairs_kernel, blocks_for(m, BLOCK), BLOCK, stream, order,
             (const Rect*)as<Rect>(ws.rects), (const uint32_t*)as<uint32_t>(ws.pair_offsets), m,
             (int)cols, as<uint32_t>(ws.pair_keys[0]), as<uint32_t>(ws.pair_values[0]));
      TRY(cudaGetLastError());
      e = radix_sort(ws, ws.pair_keys, ws.pair_values, pairs, bits_for(tiles), stream, &tile_buf);
      if (e) return e;
      LAUNCH(tile_ranges_kernel, blocks_for(pairs, BLOCK), BLOCK, stream,
             (const uint32_t*)as<uint32_t>(ws.pair_keys[tile_buf]), pairs,
             as<uint32_t>(ws.ranges));
      TRY(cudaGetLastError());
    }
  }
  stats->visible = m;
  stats->tile_pairs = pairs;
  // With no pair every tile's range is empty and the blend only writes the background; the
  // pointers below are then never read.
  const uint32_t* tile_splats = pairs > 0 ? as<uint32_t>(ws.pair_values[tile_buf]) : nullptr;
  const Splat* projected = as<Splat>(ws.splats);
  const uint32_t* tile_ranges = as<uint32_t>(ws.ranges);
  if (p.channels <= 0) {
    LAUNCH(blend_kernel<0>, tiles, BLOCK, stream, p, projected, tile_splats, tile_ranges,
           scene.features, scene.background_features, image, 0);
  }
  for (int offset = 0; offset < p.channels; offset += FEATURE_CHUNK) {
    LAUNCH(blend_kernel<FEATURE_CHUNK>, tiles, BLOCK, stream, p, projected, tile_splats,
           tile_ranges, scene.features, scene.background_features, image, offset);
    TRY(cudaGetLastError());
  }
  TRY(cudaGetLastError());
  return 0;
}

}  // namespace

extern "C" {

void* lhmpp_splat_workspace_new(void) { return new Workspace(); }

void lhmpp_splat_workspace_free(void* workspace) {
  Workspace* ws = static_cast<Workspace*>(workspace);
  if (!ws) return;
  Buffer* all[] = {&ws->splats,         &ws->rects,          &ws->visible,
                   &ws->visible_offsets, &ws->depth_bits,     &ws->keys[0],
                   &ws->keys[1],         &ws->values[0],      &ws->values[1],
                   &ws->tile_counts,     &ws->pair_offsets,   &ws->pair_keys[0],
                   &ws->pair_keys[1],    &ws->pair_values[0], &ws->pair_values[1],
                   &ws->radix_counts,    &ws->radix_offsets,  &ws->ranges,
                   &ws->total};
  for (Buffer* b : all)
    if (b->ptr) cudaFree(b->ptr);
  for (int level = 0; level < 8; ++level) {
    if (ws->scan_sums[level].ptr) cudaFree(ws->scan_sums[level].ptr);
    if (ws->scan_offsets[level].ptr) cudaFree(ws->scan_offsets[level].ptr);
  }
  delete ws;
}

int32_t lhmpp_splat_render(void* workspace, const LhmppSplatParams* params,
                           const LhmppSplatScene* scene, const LhmppSplatImage* image,
                           LhmppSplatStats* stats, void* stream) {
  return render(*static_cast<Workspace*>(workspace), *params, *scene, *image, stats,
                static_cast<cudaStream_t>(stream));
}

const char* lhmpp_splat_error_string(int32_t code) {
  return cudaGetErrorString(static_cast<cudaError_t>(code));
}

}  // extern "C"
