//! Mutations of a seed input: the byte-level ones (bit flips, interesting bytes,
//! truncation, insertion, deletion, repetition, splicing with another input) and the two
//! that aim at parsers' trust in numbers — a number in the text replaced by a huge,
//! negative or non-finite one, and binary words overwritten with extreme integers and float
//! bit patterns. Deterministic for a given random state.

/// splitmix64: small, fast, and good enough to drive mutations reproducibly.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed)
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in `0..n` (`n > 0`).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n as u64) as usize
    }
    pub fn pick<'a, T>(&mut self, items: &'a [T]) -> &'a T {
        &items[self.below(items.len())]
    }
}

/// Numbers a text parser must survive in place of any number of the input.
pub const HOSTILE_NUMBERS: &[&str] = &[
    "1e39", "-1e39", "3e38", "-3e38", "1e308", "1e400", "nan", "NaN", "inf", "-inf", "-1", "-0", "0", "1e-45",
    "4294967295", "4294967296", "2147483648", "-2147483649", "18446744073709551615", "18446744073709551616",
    "1000000000000000", "999999999999999999999999", "0.5", "1e12", "1e13", "2",
];

/// Words a binary parser must survive anywhere (little- and big-endian are both tried).
const HOSTILE_WORDS: &[u64] = &[
    0,
    1,
    0xff,
    0x7f,
    0x80,
    0xffff,
    0x8000,
    0xffff_ffff,
    0x7fff_ffff,
    0x8000_0000,
    0x7f80_0000,          // f32 +inf
    0x7fc0_0000,          // f32 NaN
    0x7f7f_ffff,          // f32 max
    0x0003_8d7e_a4c6_8000, // 1e15
    u64::MAX,
    0x7ff0_0000_0000_0000, // f64 +inf
    0x7ff8_0000_0000_0000, // f64 NaN
];

const INTERESTING_BYTES: &[u8] = b"\0\xff\x7f\x80\n\r \t-+.e9";

/// Largest input a mutation may produce (inputs stay "small": the harness's time limit is
/// meant for them).
pub const MAX_LEN: usize = 64 << 10;

/// Applies 1–4 random mutations to `input` (another corpus input, `other`, feeds splicing).
pub fn mutate(rng: &mut Rng, input: &[u8], other: &[u8]) -> Vec<u8> {
    let mut b = input.to_vec();
    let rounds = 1 + rng.below(4);
    for _ in 0..rounds {
        mutate_once(rng, &mut b, other);
    }
    b.truncate(MAX_LEN);
    b
}

fn mutate_once(rng: &mut Rng, b: &mut Vec<u8>, other: &[u8]) {
    if b.is_empty() {
        b.extend_from_slice(&other[..other.len().min(64)]);
        return;
    }
    match rng.below(10) {
        0 => {
            let i = rng.below(b.len());
            b[i] ^= 1 << rng.below(8);
        }
        1 => {
            let i = rng.below(b.len());
            b[i] = *rng.pick(INTERESTING_BYTES);
        }
        2 => {
            let at = rng.below(b.len());
            b.truncate(at);
        }
        3 => {
            let at = rng.below(b.len() + 1);
            let n = 1 + rng.below(8);
            let bytes: Vec<u8> = (0..n).map(|_| rng.next_u64() as u8).collect();
            b.splice(at..at, bytes);
        }
        4 => {
            let at = rng.below(b.len());
            let n = 1 + rng.below((b.len() - at).min(64));
            b.drain(at..at + n);
        }
        5 => {
            // Repeat a stretch (a line, a record): counts and contents disagree.
            let at = rng.below(b.len());
            let n = 1 + rng.below((b.len() - at).min(256));
            let piece = b[at..at + n].to_vec();
            let times = 1 + rng.below(8);
            for _ in 0..times {
                b.splice(at..at, piece.iter().copied());
            }
        }
        6 => {
            // Splice: the start of this input, the end of another.
            if !other.is_empty() {
                let (i, j) = (rng.below(b.len()), rng.below(other.len()));
                b.truncate(i);
                b.extend_from_slice(&other[j..]);
            }
        }
        7 | 8 => replace_number(rng, b),
        _ => overwrite_word(rng, b),
    }
}

/// Replaces one number token (digits with sign, point and exponent) by a hostile one.
fn replace_number(rng: &mut Rng, b: &mut Vec<u8>) {
    let is_num = |c: u8| c.is_ascii_digit() || matches!(c, b'-' | b'+' | b'.' | b'e' | b'E');
    let mut spans = Vec::new();
    let mut i = 0;
    while i < b.len() {
        if b[i].is_ascii_digit() {
            let mut s = i;
            while s > 0 && is_num(b[s - 1]) {
                s -= 1;
            }
            let mut e = i;
            while e < b.len() && is_num(b[e]) {
                e += 1;
            }
            spans.push((s, e));
            i = e;
        } else {
            i += 1;
        }
    }
    if spans.is_empty() {
        overwrite_word(rng, b);
        return;
    }
    let (s, e) = *rng.pick(&spans);
    let with = rng.pick(HOSTILE_NUMBERS).as_bytes().to_vec();
    b.splice(s..e, with);
}

/// Overwrites 1, 2, 4 or 8 bytes with an extreme word in either byte order.
fn overwrite_word(rng: &mut Rng, b: &mut [u8]) {
    let w = *rng.pick(HOSTILE_WORDS);
    let n = *rng.pick(&[1usize, 2, 4, 8]);
    if b.len() < n {
        return;
    }
    let at = rng.below(b.len() - n + 1);
    let bytes = if rng.below(2) == 0 { w.to_le_bytes() } else { w.to_be_bytes() };
    let src = if rng.below(2) == 0 { &bytes[..n] } else { &bytes[8 - n..] };
    b[at..at + n].copy_from_slice(src);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mutations_are_deterministic_bounded_and_varied() {
        let seed = b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n0 0 0\n1 0 0\n".to_vec();
        let run = |s: u64| {
            let mut rng = Rng::new(s);
            (0..200).map(|_| mutate(&mut rng, &seed, b"other input 12")).collect::<Vec<_>>()
        };
        let a = run(7);
        assert_eq!(a, run(7), "same seed, same mutations");
        assert!(a.iter().all(|m| m.len() <= MAX_LEN));
        let distinct: std::collections::HashSet<_> = a.iter().collect();
        assert!(distinct.len() > 150, "{} distinct of 200", distinct.len());
        // Every kind shows up: hostile numbers, truncations, growth.
        assert!(a.iter().any(|m| HOSTILE_NUMBERS.iter().any(|h| h.len() > 3 && m.windows(h.len()).any(|w| w == h.as_bytes()))));
        assert!(a.iter().any(|m| m.len() < seed.len() / 2));
        assert!(a.iter().any(|m| m.len() > seed.len() + 8));
    }
}
