// Test driver of the CPU emulation: reads a scene file written by tests/splat_cuda_emulation.rs,
// renders it with rasterize.cu's host code and kernels (built against emulate.h) and writes the
// maps. Scene file (little-endian): "LHSPLAT1", u32 sizeof(LhmppSplatParams), the params, then
// f32 arrays positions, scales, rotations, opacities, sh, features, background_features.
// Output file: u32 visible, u32 tile_pairs, then f32 rgb, alpha, depth, features.
#include <cstdio>
#include <cstring>
#include <vector>

#include "rasterize.h"

namespace {
bool read_all(const char* path, std::vector<char>& data) {
  FILE* f = std::fopen(path, "rb");
  if (!f) return false;
  char chunk[1 << 16];
  size_t got;
  while ((got = std::fread(chunk, 1, sizeof chunk, f)) > 0) data.insert(data.end(), chunk, chunk + got);
  std::fclose(f);
  return true;
}

struct Reader {
  const std::vector<char>& data;
  size_t at = 0;
  bool ok = true;
  void bytes(void* dst, size_t n) {
    if (at + n > data.size()) {
      ok = false;
      return;
    }
    std::memcpy(dst, data.data() + at, n);
    at += n;
  }
  std::vector<float> floats(size_t n) {
    std::vector<float> v(n);
    bytes(v.data(), n * sizeof(float));
    return v;
  }
};
}  // namespace

int main(int argc, char** argv) {
  if (argc != 3) {
    std::fprintf(stderr, "usage: %s SCENE OUTPUT\n", argv[0]);
    return 2;
  }
  std::vector<char> data;
  if (!read_all(argv[1], data)) {
    std::fprintf(stderr, "cannot read %s\n", argv[1]);
    return 1;
  }
  Reader in{data};
  char magic[8];
  uint32_t size = 0;
  LhmppSplatParams p;
  in.bytes(magic, 8);
  in.bytes(&size, 4);
  if (!in.ok || std::memcmp(magic, "LHSPLAT1", 8) != 0 || size != sizeof p) {
    std::fprintf(stderr, "%s: not a scene file of this layout\n", argv[1]);
    return 1;
  }
  in.bytes(&p, sizeof p);
  size_t n = p.num_gaussians, c = p.channels, k = (p.sh_degree + 1) * (p.sh_degree + 1);
  std::vector<float> positions = in.floats(n * 3), scales = in.floats(n * 3),
                     rotations = in.floats(n * 4), opacities = in.floats(n),
                     sh = in.floats(n * k * 3), features = in.floats(n * c),
                     background_features = in.floats(c);
  if (!in.ok || in.at != data.size()) {
    std::fprintf(stderr, "%s: truncated or oversized scene file\n", argv[1]);
    return 1;
  }
  size_t pixels = (size_t)p.width * p.height;
  std::vector<float> rgb(pixels * 3), alpha(pixels), depth(pixels), feature_map(pixels * c);
  LhmppSplatScene scene = {positions.data(), scales.data(),    rotations.data(),
                           opacities.data(), sh.data(),        c ? features.data() : nullptr,
                           c ? background_features.data() : nullptr};
  LhmppSplatImage image = {rgb.data(), alpha.data(), depth.data(),
                           c ? feature_map.data() : nullptr};
  LhmppSplatStats stats;
  void* ws = lhmpp_splat_workspace_new();
  // Twice through one workspace, as a renderer reuses it from frame to frame.
  int32_t code = lhmpp_splat_render(ws, &p, &scene, &image, &stats, nullptr);
  if (code == 0) code = lhmpp_splat_render(ws, &p, &scene, &image, &stats, nullptr);
  lhmpp_splat_workspace_free(ws);
  if (code != 0) {
    std::fprintf(stderr, "render failed: %s\n", lhmpp_splat_error_string(code));
    return 1;
  }
  FILE* out = std::fopen(argv[2], "wb");
  if (!out) {
    std::fprintf(stderr, "cannot write %s\n", argv[2]);
    return 1;
  }
  std::fwrite(&stats.visible, 4, 1, out);
  std::fwrite(&stats.tile_pairs, 4, 1, out);
  std::fwrite(rgb.data(), sizeof(float), rgb.size(), out);
  std::fwrite(alpha.data(), sizeof(float), alpha.size(), out);
  std::fwrite(depth.data(), sizeof(float), depth.size(), out);
  std::fwrite(feature_map.data(), sizeof(float), feature_map.size(), out);
  return std::fclose(out) == 0 ? 0 : 1;
}
