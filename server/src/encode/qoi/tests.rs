//! The band encoder against a direct port of the reference encoder (qoi.h) and, split into
//! bands, round trips through the `image` crate's QOI decoder.
use super::*;
use crate::rng::Rng;

/// qoi.h's encoder, line by line, for a whole RGB image in one go (the oracle).
fn reference_encode(pixels: &[u32], width: u32, height: u32) -> Vec<u8> {
    let mut out = header(width, height).to_vec();
    let mut index = [0u32; 64];
    let mut prev = START_PIXEL;
    let mut run = 0u8;
    for (i, &px) in pixels.iter().enumerate() {
        if px == prev {
            run += 1;
            if run == 62 || i == pixels.len() - 1 {
                out.push(0xc0 | (run - 1));
                run = 0;
            }
        } else {
            if run > 0 {
                out.push(0xc0 | (run - 1));
                run = 0;
            }
            let [r, g, b, a] = px.to_le_bytes();
            let h = (r as usize * 3 + g as usize * 5 + b as usize * 7 + a as usize * 11) % 64;
            if index[h] == px {
                out.push(h as u8);
            } else {
                index[h] = px;
                let [pr, pg, pb, _] = prev.to_le_bytes();
                let vr = r.wrapping_sub(pr) as i8;
                let vg = g.wrapping_sub(pg) as i8;
                let vb = b.wrapping_sub(pb) as i8;
                let vg_r = vr.wrapping_sub(vg);
                let vg_b = vb.wrapping_sub(vg);
                if vr > -3 && vr < 2 && vg > -3 && vg < 2 && vb > -3 && vb < 2 {
                    out.push(0x40 | ((vr + 2) as u8) << 4 | ((vg + 2) as u8) << 2 | (vb + 2) as u8);
                } else if vg_r > -9 && vg_r < 8 && vg > -33 && vg < 32 && vg_b > -9 && vg_b < 8 {
                    out.push(0x80 | (vg + 32) as u8);
                    out.push(((vg_r + 8) as u8) << 4 | (vg_b + 8) as u8);
                } else {
                    out.extend_from_slice(&[0xfe, r, g, b]);
                }
            }
        }
        prev = px;
    }
    out.extend_from_slice(&END_MARKER);
    out
}

/// Encodes with the band encoder, cutting the image before each pixel index in `cuts`.
fn band_encode(pixels: &[u32], width: u32, height: u32, cuts: &[usize]) -> Vec<u8> {
    let mut out = header(width, height).to_vec();
    let mut starts = vec![0];
    starts.extend(cuts.iter().copied().filter(|&c| c > 0 && c < pixels.len()));
    starts.push(pixels.len());
    for w in starts.windows(2) {
        let prev = if w[0] == 0 { START_PIXEL } else { pixels[w[0] - 1] };
        // A reused buffer holds old bytes: the band must not depend on them.
        let mut band = vec![0xa5u8; (w[1] - w[0]) % 7];
        let mut enc = BandEncoder::new(prev, &mut band);
        // Feed the band in uneven pieces: the state carries over between pushes.
        let mut at = w[0];
        let mut step = 1;
        while at < w[1] {
            let end = (at + step).min(w[1]);
            enc.push(&pixels[at..end]);
            at = end;
            step = step * 3 + 1;
        }
        let len = enc.finish();
        out.extend_from_slice(&band[..len]);
    }
    out.extend_from_slice(&END_MARKER);
    out
}

fn decode(bytes: &[u8], width: u32, height: u32) -> Vec<u32> {
    let img = image::load_from_memory_with_format(bytes, image::ImageFormat::Qoi).expect("decodes").into_rgb8();
    assert_eq!((img.width(), img.height()), (width, height));
    img.pixels().map(|p| u32::from_le_bytes([p.0[0], p.0[1], p.0[2], 255])).collect()
}

fn rgb(r: u8, g: u8, b: u8) -> u32 {
    u32::from_le_bytes([r, g, b, 255])
}

/// Images that use every op: runs (longer than 62, of the start pixel, across band
/// boundaries), repeats of earlier colours (index hits), small and medium steps, jumps.
fn test_image(rng: &mut Rng, n: usize) -> Vec<u32> {
    let palette: Vec<u32> = (0..8).map(|_| rgb(rng.next_u64() as u8, rng.next_u64() as u8, rng.next_u64() as u8)).collect();
    let mut px = Vec::with_capacity(n);
    let mut cur = START_PIXEL;
    while px.len() < n {
        let len = 1 + (rng.next_u64() % 90) as usize;
        let mode = rng.next_u64() % 6;
        for _ in 0..len.min(n - px.len()) {
            cur = match mode {
                0 => cur,
                1 => palette[(rng.next_u64() % 8) as usize],
                2 => {
                    let [r, g, b, _] = cur.to_le_bytes();
                    let d = |v: u8, rng: &mut Rng| v.wrapping_add((rng.next_u64() % 4) as u8).wrapping_sub(2);
                    rgb(d(r, rng), d(g, rng), d(b, rng))
                }
                3 => {
                    let [r, g, b, _] = cur.to_le_bytes();
                    let dg = (rng.next_u64() % 64) as u8;
                    let d = |v: u8, rng: &mut Rng| v.wrapping_add(dg).wrapping_add((rng.next_u64() % 16) as u8).wrapping_sub(40);
                    rgb(d(r, rng), g.wrapping_add(dg).wrapping_sub(32), d(b, rng))
                }
                4 => rgb(rng.next_u64() as u8, rng.next_u64() as u8, rng.next_u64() as u8),
                _ => START_PIXEL,
            };
            px.push(cur);
        }
    }
    px
}

#[test]
fn one_band_is_byte_identical_to_the_reference_encoder() {
    let mut rng = Rng(3);
    for case in 0..200 {
        let (w, h) = (1 + (rng.next_u64() % 70) as u32, 1 + (rng.next_u64() % 40) as u32);
        let px = test_image(&mut rng, (w * h) as usize);
        let want = reference_encode(&px, w, h);
        assert_eq!(band_encode(&px, w, h, &[]), want, "case {case} ({w}x{h})");
        assert_eq!(decode(&want, w, h), px, "case {case}: the oracle itself round-trips");
    }
}

#[test]
fn bands_join_into_a_stream_any_decoder_reads_exactly() {
    let mut rng = Rng(9);
    for case in 0..300 {
        let (w, h) = (1 + (rng.next_u64() % 64) as u32, 1 + (rng.next_u64() % 48) as u32);
        let n = (w * h) as usize;
        let px = test_image(&mut rng, n);
        let mut cuts: Vec<usize> = (0..rng.next_u64() % 12).map(|_| (rng.next_u64() % n as u64) as usize).collect();
        if case % 3 == 0 {
            // Cut on rows, as the frame encoder does.
            cuts = (1..h as usize).step_by(1 + case % 5).map(|y| y * w as usize).collect();
        }
        cuts.sort_unstable();
        cuts.dedup();
        let bytes = band_encode(&px, w, h, &cuts);
        assert_eq!(decode(&bytes, w, h), px, "case {case} ({w}x{h}), cuts {cuts:?}");
    }
}

#[test]
fn runs_across_band_boundaries_and_of_the_start_pixel() {
    // A flat image (one long run of the start pixel, then of one colour), cut everywhere.
    let (w, h) = (50u32, 9u32);
    let n = (w * h) as usize;
    let px: Vec<u32> = (0..n).map(|i| if i < 130 { START_PIXEL } else { rgb(10, 200, 30) }).collect();
    for step in [1usize, 2, 7, 61, 62, 63, 124, 200] {
        let cuts: Vec<usize> = (step..n).step_by(step).collect();
        let bytes = band_encode(&px, w, h, &cuts);
        assert_eq!(decode(&bytes, w, h), px, "bands of {step} pixels");
    }
    // In one band: runs of 62 (one byte each) and a remainder.
    let bytes = band_encode(&px, w, h, &[]);
    assert_eq!(bytes, reference_encode(&px, w, h));
    assert_eq!(bytes.len(), HEADER_LEN + 3 + 4 + 6 + END_MARKER.len(), "a 130-pixel run (62 + 62 + 6), RGB, a 319-pixel run (5 x 62 + 9)");
}

#[test]
fn eight_pixels_at_a_time_write_the_bytes_of_the_scalar_loop() {
    // Rows of every length around the eight-pixel blocks, pushed in pieces of every size,
    // from every kind of start (mid-run, after an index write): the dispatching push (AVX2
    // where the CPU has it) against the scalar loop alone.
    let mut rng = Rng(21);
    for case in 0..400 {
        let n = 1 + (rng.next_u64() % 300) as usize;
        let px = test_image(&mut rng, n);
        let prev = if case % 4 == 0 {
            START_PIXEL
        } else {
            px[(rng.next_u64() % n as u64) as usize]
        };
        let piece = 1 + (rng.next_u64() % 70) as usize;
        let (mut a, mut b) = (Vec::new(), Vec::new());
        let mut fast = BandEncoder::new(prev, &mut a);
        for chunk in px.chunks(piece) {
            fast.push(chunk);
        }
        let fast_len = fast.finish();
        let mut slow = BandEncoder::new(prev, &mut b);
        for chunk in px.chunks(piece) {
            let need = slow.len + MAX_BYTES_PER_PIXEL * chunk.len() + 4;
            if slow.buf.len() < need {
                slow.buf.resize(need, 0);
            }
            slow.push_scalar(chunk);
        }
        let slow_len = slow.finish();
        assert_eq!(
            a[..fast_len],
            b[..slow_len],
            "case {case}: {n} pixels in pieces of {piece}"
        );
    }
}
