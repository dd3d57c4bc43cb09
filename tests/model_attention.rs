//! The fused CPU attention against a naive f64 reference and against the plain candle path,
//! over odd sizes (a single query, lengths that are not multiples of the blocks, one and many
//! heads).

use candle_core::{Device, Tensor};
use lhmpp::kernels::fused_attention::{fused_attention, KEY_BLOCK, QUERY_BLOCK};
use lhmpp::model::attention::{attention, attention_reference};

/// Random `[b, h, l, d]` tensor with a fixed seed per call site.
fn randn(b: usize, h: usize, l: usize, d: usize, seed: u64) -> Tensor {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let data: Vec<f32> = (0..b * h * l * d)
        .map(|_| rng.gen_range(-2.0f32..2.0))
        .collect();
    Tensor::from_vec(data, (b, h, l, d), &Device::Cpu).unwrap()
}

/// `softmax(q kᵀ / sqrt(D)) v` with explicit loops in f64.
fn naive(q: &Tensor, k: &Tensor, v: &Tensor) -> Vec<f64> {
    let (b, h, lq, d) = q.dims4().unwrap();
    let lk = k.dim(2).unwrap();
    let q = q.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    let k = k.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    let v = v.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    let mut out = vec![0f64; b * h * lq * d];
    let mut s = vec![0f64; lk];
    for bh in 0..b * h {
        for i in 0..lq {
            for (j, sj) in s.iter_mut().enumerate() {
                let dot: f64 = (0..d)
                    .map(|c| q[(bh * lq + i) * d + c] as f64 * k[(bh * lk + j) * d + c] as f64)
                    .sum();
                *sj = dot / (d as f64).sqrt();
            }
            let mx = s.iter().cloned().fold(f64::MIN, f64::max);
            s.iter_mut().for_each(|x| *x = (*x - mx).exp());
            let z: f64 = s.iter().sum();
            for c in 0..d {
                out[(bh * lq + i) * d + c] = (0..lk)
                    .map(|j| s[j] / z * v[(bh * lk + j) * d + c] as f64)
                    .sum::<f64>();
            }
        }
    }
    out
}

/// Largest absolute difference between the fused output and the naive reference.
fn fused_error(b: usize, h: usize, lq: usize, lk: usize, d: usize) -> f64 {
    let seed = (b * 1_000_003 + h * 10_007 + lq * 101 + lk * 7 + d) as u64;
    let q = randn(b, h, lq, d, seed);
    let k = randn(b, h, lk, d, seed + 1);
    let v = randn(b, h, lk, d, seed + 2);
    let got = fused_attention(&q, &k, &v)
        .unwrap()
        .flatten_all()
        .unwrap()
        .to_vec1::<f32>()
        .unwrap();
    let want = naive(&q, &k, &v);
    assert_eq!(got.len(), want.len());
    got.iter()
        .zip(&want)
        .map(|(g, w)| (*g as f64 - w).abs())
        .fold(0.0, f64::max)
}

#[test]
fn fused_attention_equals_the_naive_reference_over_odd_sizes() {
    let mut worst = 0f64;
    for &l in &[1usize, 7, 33, 130, 1000] {
        for &d in &[8usize, 16, 32, 64] {
            for &(b, h) in &[(1usize, 1usize), (2, 3)] {
                // The naive reference is O(L²·D) per head: keep the big case to one head.
                if l == 1000 && (b, h) != (1, 1) {
                    continue;
                }
                let err = fused_error(b, h, l, l, d);
                assert!(err < 1e-5, "L={l} D={d} B={b} H={h}: max abs diff {err}");
                worst = worst.max(err);
            }
        }
    }
    eprintln!("worst max abs diff against the f64 reference: {worst:e}");
}

#[test]
fn fused_attention_handles_more_keys_than_queries_and_the_reverse() {
    // Cross attention: lengths straddling the block sizes in both directions.
    for &(lq, lk) in &[
        (1, KEY_BLOCK + 1),
        (QUERY_BLOCK + 1, 3),
        (2 * QUERY_BLOCK, 2 * KEY_BLOCK - 1),
    ] {
        let err = fused_error(1, 2, lq, lk, 16);
        assert!(err < 1e-5, "Lq={lq} Lk={lk}: max abs diff {err}");
    }
}

#[test]
fn shared_attention_on_cpu_matches_the_plain_candle_path_with_many_heads() {
    let q = randn(2, 8, 300, 32, 11);
    let k = randn(2, 8, 517, 32, 12);
    let v = randn(2, 8, 517, 32, 13);
    let fused = attention(&q, &k, &v, None).unwrap();
    let plain = attention_reference(&q, &k, &v, None).unwrap();
    let diff = (fused - plain)
        .unwrap()
        .abs()
        .unwrap()
        .max_all()
        .unwrap()
        .to_scalar::<f32>()
        .unwrap();
    assert!(diff < 1e-5, "{diff}");
}

#[test]
fn fused_attention_accepts_views_with_a_start_offset() {
    // The PTv3 block feeds q, k, v as `get(i)` of one contiguous [3, ...] tensor.
    let qkv = randn(3, 2, 70, 16, 21);
    let (q, k, v) = (
        qkv.get(0).unwrap(),
        qkv.get(1).unwrap(),
        qkv.get(2).unwrap(),
    );
    let (q, k, v) = (
        q.unsqueeze(0).unwrap(),
        k.unsqueeze(0).unwrap(),
        v.unsqueeze(0).unwrap(),
    );
    let got = fused_attention(&q, &k, &v).unwrap();
    let want = fused_attention(&q.copy().unwrap(), &k.copy().unwrap(), &v.copy().unwrap()).unwrap();
    let diff = (got - want).unwrap().abs().unwrap().max_all().unwrap();
    assert_eq!(diff.to_scalar::<f32>().unwrap(), 0.0);
}

#[test]
fn fused_attention_rejects_non_contiguous_and_mismatched_operands() {
    let q = randn(1, 2, 5, 8, 31);
    let k = randn(1, 2, 6, 8, 32);
    let v = randn(1, 2, 6, 8, 33);
    let transposed = k
        .transpose(2, 3)
        .unwrap()
        .contiguous()
        .unwrap()
        .transpose(2, 3)
        .unwrap();
    let err = fused_attention(&q, &transposed, &v)
        .unwrap_err()
        .to_string();
    assert!(err.contains("`k` is not contiguous"), "{err}");
    let short_v = randn(1, 2, 4, 8, 34);
    let err = fused_attention(&q, &k, &short_v).unwrap_err().to_string();
    assert!(err.contains("do not match"), "{err}");
}
