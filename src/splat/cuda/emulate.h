// CPU emulation of the small part of CUDA that rasterize.cu uses, so that the very same kernels
// and host code run (slowly) on a machine without a GPU: tests compare them with the Rust CPU
// rasteriser. Blocks run one after another; each CUDA thread of a block is an OS thread, and
// __syncthreads is a barrier among them. `__shared__` variables become function statics, which
// all threads of the running block share (correct only because blocks never overlap).
// 1-D launches only. Not for production use.
#ifndef LHMPP_SPLAT_EMULATE_H
#define LHMPP_SPLAT_EMULATE_H

#include <atomic>
#include <barrier>
#include <cstdlib>
#include <cstring>
#include <thread>
#include <vector>

#define __global__
#define __device__
#define __host__
#define __forceinline__ inline
#define __shared__ static

namespace emu {
struct Dim {
  unsigned x;
};
inline thread_local Dim thread_idx{0}, block_idx{0}, block_dim{1}, grid_dim{1};
inline thread_local std::barrier<>* block_barrier = nullptr;
inline std::atomic<int> sync_counter{0};

inline void sync() { block_barrier->arrive_and_wait(); }

// __syncthreads_count: a barrier that also counts the threads whose predicate holds.
inline int sync_count(int predicate) {
  if (predicate) sync_counter.fetch_add(1);
  sync();
  int count = sync_counter.load();
  sync();
  if (thread_idx.x == 0) sync_counter.store(0);
  sync();
  return count;
}

// Runs `kernel(args...)` on `blocks` blocks of `threads` threads (arguments evaluated once, at
// the launch, as in CUDA).
template <class... Params, class... Args>
void launch(unsigned blocks, unsigned threads, void (*kernel)(Params...), Args... args) {
  std::barrier<> barrier(threads);
  for (unsigned b = 0; b < blocks; ++b) {
    std::vector<std::thread> pool;
    pool.reserve(threads);
    for (unsigned t = 0; t < threads; ++t) {
      pool.emplace_back([&, b, t] {
        thread_idx = {t};
        block_idx = {b};
        block_dim = {threads};
        grid_dim = {blocks};
        block_barrier = &barrier;
        kernel(args...);
      });
    }
    for (auto& th : pool) th.join();
  }
}
}  // namespace emu

#define threadIdx (emu::thread_idx)
#define blockIdx (emu::block_idx)
#define blockDim (emu::block_dim)
#define gridDim (emu::grid_dim)
#define __syncthreads() emu::sync()
#define __syncthreads_count(p) emu::sync_count(p)
#define LAUNCH(kernel, blocks, threads, stream, ...) \
  emu::launch((blocks), (threads), kernel, __VA_ARGS__)

template <class T>
inline T atomicAdd(T* address, T value) {
  return __atomic_fetch_add(address, value, __ATOMIC_RELAXED);
}

typedef int cudaError_t;
typedef void* cudaStream_t;
enum { cudaSuccess = 0, cudaErrorMemoryAllocation = 2 };
enum cudaMemcpyKind { cudaMemcpyDeviceToHost = 2 };
inline cudaError_t cudaMalloc(void** ptr, size_t bytes) {
  *ptr = std::malloc(bytes ? bytes : 1);
  return *ptr ? cudaSuccess : cudaErrorMemoryAllocation;
}
inline cudaError_t cudaFree(void* ptr) {
  std::free(ptr);
  return cudaSuccess;
}
inline cudaError_t cudaMemsetAsync(void* ptr, int value, size_t bytes, cudaStream_t) {
  std::memset(ptr, value, bytes);
  return cudaSuccess;
}
inline cudaError_t cudaMemcpyAsync(void* dst, const void* src, size_t bytes, cudaMemcpyKind,
                                   cudaStream_t) {
  std::memcpy(dst, src, bytes);
  return cudaSuccess;
}
inline cudaError_t cudaStreamSynchronize(cudaStream_t) { return cudaSuccess; }
inline cudaError_t cudaGetLastError() { return cudaSuccess; }
inline const char* cudaGetErrorString(cudaError_t code) {
  return code == cudaSuccess ? "no error" : "emulated allocation failed";
}

#endif
