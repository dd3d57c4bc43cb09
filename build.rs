//! Build script: with the `cuda` feature, compiles the CUDA splatting rasteriser
//! (`src/splat/cuda/rasterize.cu`) with nvcc into a static library. With a compiler of Rust
//! 1.89 or newer (AVX-512 intrinsics stable) it sets `lhmpp_bf16_intrinsics`, which compiles
//! the AVX512-BF16 kernels of `kernels::bf16` (older compilers, down to the crate's 1.85, get
//! the portable kernel only).
//! Env: `NVCC` (default `nvcc` on PATH), `CUDA_COMPUTE_CAP` (default 90, the H100),
//! `CUDA_ROOT`/`CUDA_PATH` (where libcudart is; see scripts/build-cuda).

/// Whether the compiler running this build is Rust 1.89 or newer.
fn rustc_at_least_1_89() -> bool {
    let rustc = std::env::var("RUSTC").unwrap_or_else(|_| "rustc".into());
    let Ok(out) = std::process::Command::new(rustc).arg("--version").output() else {
        return false;
    };
    let text = String::from_utf8_lossy(&out.stdout);
    // "rustc 1.95.0 (59807616e 2026-04-14)"
    let mut parts = text
        .split_whitespace()
        .nth(1)
        .unwrap_or("")
        .split('.')
        .map(|p| p.parse::<u32>().unwrap_or(0));
    let (major, minor) = (parts.next().unwrap_or(0), parts.next().unwrap_or(0));
    (major, minor) >= (1, 89)
}

fn main() {
    println!("cargo:rustc-check-cfg=cfg(lhmpp_bf16_intrinsics)");
    if rustc_at_least_1_89() {
        println!("cargo:rustc-cfg=lhmpp_bf16_intrinsics");
    }
    for file in ["rasterize.cu", "rasterize.h"] {
        println!("cargo:rerun-if-changed=src/splat/cuda/{file}");
    }
    println!("cargo:rerun-if-env-changed=CUDA_COMPUTE_CAP");
    if std::env::var_os("CARGO_FEATURE_CUDA").is_none() {
        return;
    }
    let arch = std::env::var("CUDA_COMPUTE_CAP").unwrap_or_else(|_| "90".into());
    let arch = arch.trim_end_matches(['a', 'f']);
    cc::Build::new()
        .cuda(true)
        .cudart("none")
        .flag("-std=c++17")
        .flag("-O3")
        .flag(format!(
            "-gencode=arch=compute_{arch},code=[sm_{arch},compute_{arch}]"
        ))
        .file("src/splat/cuda/rasterize.cu")
        .compile("lhmpp_splat_cuda");
    for var in ["CUDA_ROOT", "CUDA_PATH", "CUDA_HOME"] {
        if let Ok(root) = std::env::var(var) {
            println!("cargo:rustc-link-search=native={root}/lib");
            println!("cargo:rustc-link-search=native={root}/lib64");
            break;
        }
    }
    println!("cargo:rustc-link-lib=cudart");
}
