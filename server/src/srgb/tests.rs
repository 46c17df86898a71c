//! The table against the f64 formula on every float it maps, the special inputs, and the row
//! encoders against the per-channel one.
use super::*;
use crate::image_metrics::{linear_to_srgb, srgb8_to_linear};
use crate::rng::Rng;
use rayon::prelude::*;

/// Every float in [2^-13, 1] (109 M of them): the table gives the correctly rounded code.
/// Where the f32 `powf` formula disagrees, it is the formula's own rounding error: the
/// exact value lies within 2e-5 of a code's rounding boundary there.
#[test]
fn every_float_in_the_table_range_is_correctly_rounded() {
    let t = table();
    let (mismatches, f32_disagreements) = (0..BUCKETS as u32)
        .into_par_iter()
        .map(|i| {
            let start = LO_BITS + (i << SHIFT);
            let end = if start == ONE_BITS { start + 1 } else { start + NO_BOUNDARY };
            let (mut bad, mut f32_off) = (0u64, 0u64);
            // The row encoders (the AVX2 path where the CPU has it) on the same floats.
            let floats: Vec<f32> = (start..end).map(f32::from_bits).collect();
            let pixels: Vec<Vec3> = floats.chunks(3).map(|c| Vec3::new(c[0], c[c.len().min(2) - 1], c[c.len() - 1])).collect();
            let mut rgb = vec![0u8; 3 * pixels.len()];
            encode_row_rgb(&pixels, &mut rgb);
            let mut rgba = vec![0u32; pixels.len()];
            encode_row_rgba(&pixels, &mut rgba);
            for (i, p) in pixels.iter().enumerate() {
                let want = [encode_with(t, p.x), encode_with(t, p.y), encode_with(t, p.z)];
                bad += (rgb[3 * i..3 * i + 3] != want) as u64;
                bad += (rgba[i].to_le_bytes() != [want[0], want[1], want[2], 255]) as u64;
            }
            for bits in start..end {
                let x = f32::from_bits(bits);
                let got = encode_with(t, x);
                if got != reference_code(x) {
                    bad += 1;
                }
                let formula = (linear_to_srgb(x) * 255.0).round() as u8;
                if formula != got {
                    let exact = encode_f64(x as f64) * 255.0;
                    let to_boundary = (exact - exact.floor() - 0.5).abs();
                    assert!(to_boundary < 2e-5, "x = {x:e}: table {got}, f32 formula {formula}, exact {exact}");
                    f32_off += 1;
                }
            }
            (bad, f32_off)
        })
        .reduce(|| (0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    assert_eq!(mismatches, 0, "floats whose table code differs from the f64 formula");
    eprintln!("floats in [2^-13, 1] where the f32 powf formula misrounds: {f32_disagreements}");
    // The f32 formula misrounds a few floats next to the 255 boundaries, nowhere else.
    assert!(f32_disagreements < 4096, "{f32_disagreements} floats where the f32 powf formula differs");
}

/// The f64 reference decides every boundary with a wide margin: at the last float below and
/// the first float at each boundary the exact value is far further from the half-code than
/// f64 rounding can move it, so the reference itself is the exact rounding.
#[test]
fn rounding_boundaries_are_decided_with_margin() {
    let t = table();
    let mut found = 0;
    for (i, &e) in t.iter().enumerate() {
        let offset = e & 0x00ff_ffff;
        if offset == NO_BOUNDARY {
            continue;
        }
        found += 1;
        let first = LO_BITS + ((i as u32) << SHIFT) + offset;
        let code = (e >> 24) + 1;
        for bits in [first - 1, first] {
            let exact = encode_f64(f32::from_bits(bits) as f64) * 255.0;
            assert!((exact - (code as f64 - 0.5)).abs() > 1e-9, "code {code}: {exact} too close to call");
        }
        assert_eq!(encode(f32::from_bits(first - 1)) as u32, code - 1);
        assert_eq!(encode(f32::from_bits(first)) as u32, code);
    }
    assert_eq!(found, 255, "one boundary per code step");
}

#[test]
fn special_and_out_of_range_inputs() {
    for (x, want) in [
        (f32::NAN, 0u8),
        (-f32::NAN, 0),
        (f32::from_bits(0x7fc0_1234), 0),
        (f32::from_bits(0xffff_ffff), 0),
        (0.0, 0),
        (-0.0, 0),
        (-1e-30, 0),
        (-3.0, 0),
        (f32::NEG_INFINITY, 0),
        (f32::MIN_POSITIVE, 0),
        (f32::from_bits(1), 0),
        (f32::from_bits(LO_BITS - 1), 0),
        (1.0, 255),
        (1.000_001, 255),
        (7.0, 255),
        (f32::MAX, 255),
        (f32::INFINITY, 255),
    ] {
        assert_eq!(encode(x), want, "x = {x:e} ({:#x})", x.to_bits());
    }
    // Random bit patterns cover everything outside the table range too.
    let mut r = Rng(11);
    for _ in 0..2_000_000 {
        let x = f32::from_bits(r.next_u64() as u32);
        assert_eq!(encode(x), reference_code(x), "x = {x:e} ({:#x})", x.to_bits());
    }
}

#[test]
fn every_code_round_trips() {
    for k in 0..=255u8 {
        assert_eq!(encode_rgb(srgb8_to_linear([k, k, k])), [k, k, k], "code {k}");
    }
}

#[test]
fn row_encoders_match_the_channel_encoder() {
    let mut r = Rng(5);
    let specials = [f32::NAN, -f32::NAN, -1.0, 0.0, -0.0, 1.0, 2.0, f32::INFINITY, 1e-5, 0.003_130_8];
    for len in [0usize, 1, 2, 3, 7, 8, 9, 15, 16, 17, 31, 64, 333] {
        let src: Vec<Vec3> = (0..len)
            .map(|_| {
                let mut ch = || match r.next_u64() % 8 {
                    0 => specials[(r.next_u64() % specials.len() as u64) as usize],
                    _ => r.unit() * 1.1 - 0.05,
                };
                Vec3::new(ch(), ch(), ch())
            })
            .collect();
        let want: Vec<[u8; 3]> = src.iter().map(|&c| encode_rgb(c)).collect();
        let mut rgba = vec![0u32; len];
        encode_row_rgba(&src, &mut rgba);
        let mut rgba_generic = vec![0u32; len];
        encode_row_rgba_generic(table(), &src, &mut rgba_generic);
        let mut rgb = vec![0u8; 3 * len];
        encode_row_rgb(&src, &mut rgb);
        let mut rgb_generic = vec![0u8; 3 * len];
        encode_row_rgb_generic(table(), &src, &mut rgb_generic);
        for i in 0..len {
            let [a, b, c] = want[i];
            let packed = a as u32 | (b as u32) << 8 | (c as u32) << 16 | 0xff00_0000;
            assert_eq!(rgba[i], packed, "len {len} pixel {i} {:?}", src[i]);
            assert_eq!(rgba_generic[i], packed);
            assert_eq!(rgb[3 * i..3 * i + 3], want[i]);
            assert_eq!(rgb_generic[3 * i..3 * i + 3], want[i]);
        }
    }
}
