//! The Intel AMX micro-kernel of the bf16 products (`tdpbf16ps` on tile registers), for CPUs
//! that have AMX-TILE and AMX-BF16 and an OS that lets the process use them.
//!
//! One `tdpbf16ps` multiplies a tile of 16 rows × 16 pairs of `k` (the left operand's rows as
//! [`super::gemm`] converts them: pairs of bf16, `lda` pairs apart) by a tile of 16 pairs × 16
//! output columns — exactly 16 columns of a [`super::PackedRhs`] tile read with a row stride of
//! one packed pair (`NR × 2` bf16), so the packed weights serve this kernel unchanged — and adds
//! the 16 × 16 products to an f32 tile. Blocks of 32 rows × 32 columns keep four output tiles,
//! two of the left and two of the right operand in the eight tile registers. Rows past the last
//! multiple of 16 and the last `k` pairs past a multiple of 16 go to the AVX512-BF16 kernel
//! (every AMX CPU has it), which adds the same bf16 products in f32.
//!
//! The tile instructions are written as inline assembly (their intrinsics are not stable Rust).
//! Each thread loads the tile configuration before it multiplies ([`Tiles::load`]) and releases
//! the tile state afterwards, so that a thread between products saves no tile data on a
//! context switch.

use std::arch::asm;
use std::sync::OnceLock;

use super::NR;

/// Rows and `k` pairs of one tile, and output columns of one tile.
const T: usize = 16;
/// Bytes between the rows of a right-operand tile: one packed pair of `NR` columns.
const RHS_STRIDE: usize = NR * 2 * 2;

/// Whether this process can run the AMX kernel: the CPU reports AMX-TILE and AMX-BF16, the OS
/// saves tile state (XCR0 bits 17 and 18), and Linux granted the tile-data permission (asked
/// once, on the first call).
pub fn available() -> bool {
    static AVAILABLE: OnceLock<bool> = OnceLock::new();
    *AVAILABLE.get_or_init(|| cpu_has_amx() && super::avx512::available() && request_tile_data())
}

fn cpu_has_amx() -> bool {
    use std::arch::x86_64::__cpuid_count;
    // SAFETY: CPUID exists on every x86-64 CPU (the call is safe on newer compilers).
    #[allow(unused_unsafe)]
    let (leaf1, leaf7) = unsafe { (__cpuid_count(1, 0), __cpuid_count(7, 0)) };
    let amx_bf16 = leaf7.edx & (1 << 22) != 0;
    let amx_tile = leaf7.edx & (1 << 24) != 0;
    let osxsave = leaf1.ecx & (1 << 27) != 0;
    if !(amx_bf16 && amx_tile && osxsave) {
        return false;
    }
    let (lo, _hi): (u32, u32);
    // SAFETY: XGETBV with ECX = 0 is valid once the OS has enabled XSAVE (OSXSAVE, checked).
    unsafe {
        asm!("xgetbv", in("ecx") 0u32, out("eax") lo, out("edx") _hi, options(nomem, nostack));
    }
    // XTILECFG (bit 17) and XTILEDATA (bit 18) enabled by the OS.
    lo & (3 << 17) == 3 << 17
}

#[cfg(target_os = "linux")]
fn request_tile_data() -> bool {
    const ARCH_REQ_XCOMP_PERM: libc::c_long = 0x1023;
    const XFEATURE_XTILEDATA: libc::c_long = 18;
    // SAFETY: arch_prctl(ARCH_REQ_XCOMP_PERM) only changes this process's permitted XSAVE
    // features; it reads and writes no memory of ours.
    unsafe {
        libc::syscall(
            libc::SYS_arch_prctl,
            ARCH_REQ_XCOMP_PERM,
            XFEATURE_XTILEDATA,
        ) == 0
    }
}

#[cfg(not(target_os = "linux"))]
fn request_tile_data() -> bool {
    false
}

/// The tile configuration: palette 1, eight tiles of 16 rows × 64 bytes.
#[repr(C, align(64))]
struct Config([u8; 64]);

const CONFIG: Config = {
    let mut c = [0u8; 64];
    c[0] = 1;
    let mut t = 0;
    while t < 8 {
        c[16 + 2 * t] = 64;
        c[48 + t] = T as u8;
        t += 1;
    }
    Config(c)
};

/// The tile registers of the calling thread, configured for this kernel while the value lives.
pub struct Tiles(());

impl Tiles {
    /// Loads the tile configuration on this thread.
    ///
    /// # Safety
    /// [`available`] must have returned true.
    pub unsafe fn load() -> Self {
        asm!("ldtilecfg [{}]", in(reg) CONFIG.0.as_ptr(), options(nostack, readonly));
        Tiles(())
    }

    /// `C[rows × cols] += A · Bᵀ` (or `=` when `add` is false) for one packed tile of the
    /// right operand, as [`super::avx512::tile`] but for any number of rows.
    ///
    /// # Safety
    /// As [`super::avx512::tile`], for `rows` rows instead of at most six.
    #[allow(clippy::too_many_arguments)]
    pub unsafe fn tile(
        &self,
        rows: usize,
        kc: usize,
        a: *const u32,
        lda: usize,
        b: *const u16,
        c: *mut f32,
        ldc: usize,
        cols: usize,
        add: bool,
    ) {
        let steps = kc / T;
        let tiled_rows = if steps > 0 { rows / T * T } else { 0 };
        let mut r0 = 0;
        while r0 < tiled_rows {
            let pair = (tiled_rows - r0).min(2 * T) / T;
            let mut j0 = 0;
            while j0 < cols {
                let (ar, cr) = (a.add(r0 * lda), c.add(r0 * ldc + j0));
                let br = b.add(j0 * 2);
                if j0 + 2 * T <= cols {
                    self.block(pair, steps, ar, lda, br, cr, ldc, add);
                } else {
                    // A part-filled column group: into zeros, then the valid columns added.
                    let mut scratch = [0f32; 4 * T * T];
                    self.block(pair, steps, ar, lda, br, scratch.as_mut_ptr(), 2 * T, false);
                    for r in 0..pair * T {
                        let row = cr.add(r * ldc);
                        for (j, &v) in scratch[r * 2 * T..][..cols - j0].iter().enumerate() {
                            *row.add(j) = if add { *row.add(j) + v } else { v };
                        }
                    }
                }
                j0 += 2 * T;
            }
            r0 += pair * T;
        }
        // The rows below the tiles, every pair; then the tiled rows' pairs past the tiles.
        let mut r = tiled_rows;
        while r < rows {
            let n = super::MR.min(rows - r);
            super::avx512::tile(
                n,
                kc,
                a.add(r * lda),
                lda,
                b,
                c.add(r * ldc),
                ldc,
                cols,
                add,
            );
            r += n;
        }
        let done = steps * T;
        if done < kc {
            let mut r = 0;
            while r < tiled_rows {
                let n = super::MR.min(tiled_rows - r);
                super::avx512::tile(
                    n,
                    kc - done,
                    a.add(r * lda + done),
                    lda,
                    b.add(done * NR * 2),
                    c.add(r * ldc),
                    ldc,
                    cols,
                    true,
                );
                r += n;
            }
        }
    }

    /// `C += A · Bᵀ` (`C = A · Bᵀ` when `add` is false) over `steps × 16` pairs for 16 or 32
    /// rows (`pair` 1 or 2) × 32 columns: output tiles 0–3, left tiles 4–5, right tiles 6–7.
    #[allow(clippy::too_many_arguments)]
    unsafe fn block(
        &self,
        pair: usize,
        steps: usize,
        a: *const u32,
        lda: usize,
        b: *const u16,
        c: *mut f32,
        ldc: usize,
        add: bool,
    ) {
        let (lda_b, ldc_b) = (lda * 4, ldc * 4);
        let c1 = c.add(T);
        if pair == 2 {
            let (c2, c3) = (c.add(T * ldc), c.add(T * ldc + T));
            if !add {
                asm!(
                    "tilezero tmm0",
                    "tilezero tmm1",
                    "tilezero tmm2",
                    "tilezero tmm3",
                    options(nostack, nomem),
                );
            } else {
                asm!(
                "tileloadd tmm0, [{c0} + {s}*1]",
                "tileloadd tmm1, [{c1} + {s}*1]",
                "tileloadd tmm2, [{c2} + {s}*1]",
                "tileloadd tmm3, [{c3} + {s}*1]",
                c0 = in(reg) c, c1 = in(reg) c1, c2 = in(reg) c2, c3 = in(reg) c3,
                s = in(reg) ldc_b, options(nostack, readonly),
                );
            }
            for q in 0..steps {
                let a0 = a.add(q * T);
                let b0 = b.add(q * T * NR * 2);
                asm!(
                    "tileloadd tmm4, [{a0} + {sa}*1]",
                    "tileloadd tmm6, [{b0} + {sb}*1]",
                    "tdpbf16ps tmm0, tmm4, tmm6",
                    "tileloadd tmm7, [{b1} + {sb}*1]",
                    "tdpbf16ps tmm1, tmm4, tmm7",
                    "tileloadd tmm5, [{a1} + {sa}*1]",
                    "tdpbf16ps tmm2, tmm5, tmm6",
                    "tdpbf16ps tmm3, tmm5, tmm7",
                    a0 = in(reg) a0, a1 = in(reg) a0.add(T * lda), sa = in(reg) lda_b,
                    b0 = in(reg) b0, b1 = in(reg) b0.add(2 * T), sb = in(reg) RHS_STRIDE,
                    options(nostack, readonly),
                );
            }
            asm!(
                "tilestored [{c0} + {s}*1], tmm0",
                "tilestored [{c1} + {s}*1], tmm1",
                "tilestored [{c2} + {s}*1], tmm2",
                "tilestored [{c3} + {s}*1], tmm3",
                c0 = in(reg) c, c1 = in(reg) c1, c2 = in(reg) c2, c3 = in(reg) c3,
                s = in(reg) ldc_b, options(nostack),
            );
        } else {
            if !add {
                asm!("tilezero tmm0", "tilezero tmm1", options(nostack, nomem));
            } else {
                asm!(
                    "tileloadd tmm0, [{c0} + {s}*1]",
                    "tileloadd tmm1, [{c1} + {s}*1]",
                    c0 = in(reg) c, c1 = in(reg) c1, s = in(reg) ldc_b,
                    options(nostack, readonly),
                );
            }
            for q in 0..steps {
                let a0 = a.add(q * T);
                let b0 = b.add(q * T * NR * 2);
                asm!(
                    "tileloadd tmm4, [{a0} + {sa}*1]",
                    "tileloadd tmm6, [{b0} + {sb}*1]",
                    "tileloadd tmm7, [{b1} + {sb}*1]",
                    "tdpbf16ps tmm0, tmm4, tmm6",
                    "tdpbf16ps tmm1, tmm4, tmm7",
                    a0 = in(reg) a0, sa = in(reg) lda_b,
                    b0 = in(reg) b0, b1 = in(reg) b0.add(2 * T), sb = in(reg) RHS_STRIDE,
                    options(nostack, readonly),
                );
            }
            asm!(
                "tilestored [{c0} + {s}*1], tmm0",
                "tilestored [{c1} + {s}*1], tmm1",
                c0 = in(reg) c, c1 = in(reg) c1, s = in(reg) ldc_b, options(nostack),
            );
        }
    }
}

impl Drop for Tiles {
    fn drop(&mut self) {
        // SAFETY: the tiles were configured by `load`; releasing returns them to their initial
        // state.
        unsafe { asm!("tilerelease", options(nostack, nomem)) };
    }
}
