//! Build script: with the `cuda` feature, compiles the CUDA splatting rasteriser
//! (`src/splat/cuda/rasterize.cu`) with nvcc into a static library. Nothing to do otherwise.
//! Env: `NVCC` (default `nvcc` on PATH), `CUDA_COMPUTE_CAP` (default 90, the H100),
//! `CUDA_ROOT`/`CUDA_PATH` (where libcudart is; see scripts/build-cuda).

fn main() {
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
