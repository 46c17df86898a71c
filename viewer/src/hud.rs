//! On-screen text for the window, drawn straight into its 0RGB pixel buffer with an 8x8
//! bitmap font (ASCII; other characters show as `?`): the stats overlay, the key help, the
//! loading screen and short notices.
use font8x8::legacy::BASIC_LEGACY;

/// Glyph size in pixels.
pub const GLYPH: usize = 8;
/// Line height in pixels.
pub const LINE: usize = 10;

/// A 0RGB pixel buffer to draw on.
pub struct Canvas<'a> {
    pub pixels: &'a mut [u32],
    pub width: usize,
    pub height: usize,
}

impl Canvas<'_> {
    /// Darkens the rectangle (x, y, w, h) to a third, clipped to the buffer: text over it
    /// stays readable on any frame.
    pub fn shade(&mut self, x: usize, y: usize, w: usize, h: usize) {
        for row in y.min(self.height)..(y + h).min(self.height) {
            let line = &mut self.pixels[row * self.width..(row + 1) * self.width];
            for p in &mut line[x.min(self.width)..(x + w).min(self.width)] {
                *p = (*p >> 2) & 0x3f3f3f;
            }
        }
    }

    /// Fills the rectangle with `color`, clipped.
    pub fn fill(&mut self, x: usize, y: usize, w: usize, h: usize, color: u32) {
        for row in y.min(self.height)..(y + h).min(self.height) {
            let line = &mut self.pixels[row * self.width..(row + 1) * self.width];
            line[x.min(self.width)..(x + w).min(self.width)].fill(color);
        }
    }

    /// Draws `text` with its top-left corner at (x, y), clipped; returns the width drawn.
    pub fn text(&mut self, x: usize, y: usize, text: &str, color: u32) -> usize {
        let mut cx = x;
        for ch in text.chars() {
            let code = if (ch as u32) < 128 { ch as usize } else { b'?' as usize };
            let glyph = BASIC_LEGACY[code];
            for (gy, bits) in glyph.iter().enumerate() {
                let py = y + gy;
                if py >= self.height {
                    break;
                }
                for gx in 0..GLYPH {
                    // Bit 0 is the leftmost pixel.
                    if bits >> gx & 1 == 1 && cx + gx < self.width {
                        self.pixels[py * self.width + cx + gx] = color;
                    }
                }
            }
            cx += GLYPH;
        }
        cx - x
    }

    /// A block of lines on a shaded box at (x, y); returns the box's height.
    pub fn panel(&mut self, x: usize, y: usize, lines: &[String], color: u32) -> usize {
        let w = lines.iter().map(|l| l.chars().count()).max().unwrap_or(0) * GLYPH + 8;
        let h = lines.len() * LINE + 6;
        self.shade(x, y, w, h);
        for (i, l) in lines.iter().enumerate() {
            self.text(x + 4, y + 4 + i * LINE, l, color);
        }
        h
    }
}

/// Splits `items` into lines of at most `max_chars` characters, joined by two spaces.
pub fn wrap(items: &[String], max_chars: usize) -> Vec<String> {
    let mut lines = Vec::new();
    let mut cur = String::new();
    for it in items {
        if !cur.is_empty() && cur.chars().count() + 2 + it.chars().count() > max_chars {
            lines.push(std::mem::take(&mut cur));
        }
        if !cur.is_empty() {
            cur.push_str("  ");
        }
        cur.push_str(it);
    }
    if !cur.is_empty() {
        lines.push(cur);
    }
    lines
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_sets_exactly_the_glyph_bits_and_clips() {
        let mut px = vec![0u32; 20 * 10];
        let mut c = Canvas { pixels: &mut px, width: 20, height: 10 };
        assert_eq!(c.text(1, 1, "A!", 0xffffff), 16);
        // Every lit pixel is a set bit of the glyph at its place, and the other way round.
        for (k, ch) in ['A', '!'].iter().enumerate() {
            for gy in 0..8 {
                for gx in 0..8 {
                    let x = 1 + k * 8 + gx;
                    if x >= 20 {
                        continue;
                    }
                    let want = BASIC_LEGACY[*ch as usize][gy] >> gx & 1 == 1;
                    assert_eq!(px[(1 + gy) * 20 + x] == 0xffffff, want, "{ch} ({gx},{gy})");
                }
            }
        }
        assert!(px.iter().any(|&p| p != 0));
        // Far outside: nothing drawn, no panic.
        let mut c = Canvas { pixels: &mut px, width: 20, height: 10 };
        c.text(100, 100, "x", 1);
        c.shade(15, 5, 100, 100);
    }

    #[test]
    fn shade_darkens_and_wrap_keeps_lines_short() {
        let mut px = vec![0x808080u32; 4];
        Canvas { pixels: &mut px, width: 2, height: 2 }.shade(1, 0, 5, 1);
        assert_eq!(px, vec![0x808080, 0x202020, 0x808080, 0x808080]);
        let items: Vec<String> = ["aaaa", "bbb", "cc", "dddddd"].iter().map(|s| s.to_string()).collect();
        assert_eq!(wrap(&items, 10), vec!["aaaa  bbb", "cc  dddddd"]);
        assert_eq!(wrap(&items, 6), vec!["aaaa", "bbb", "cc", "dddddd"]);
    }
}
