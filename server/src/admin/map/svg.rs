//! Vector maps: sample colours as row runs of rectangles (crisp edges),
//! contour lines as paths, a title and a legend of the colours used.

use std::fmt::Write as _;
use std::io::Write;

use super::palette::hex;
use super::{MapError, MapImage};

/// Legend row height in pixels, under the map.
const LEGEND_ROW: u32 = 16;

/// Escapes text for XML character data and attribute values.
fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            c if (c as u32) < 0x20 && c != '\n' && c != '\t' => out.push(' '),
            c => out.push(c),
        }
    }
    out
}

/// Writes the map as a standalone SVG 1.1 document.
pub fn write_svg(map: &MapImage, out: &mut impl Write) -> Result<(), std::io::Error> {
    let (w, h) = map
        .pixel_size()
        .map_err(|e: MapError| std::io::Error::new(std::io::ErrorKind::InvalidInput, e))?;
    let legend_h = LEGEND_ROW * map.legend.len() as u32;
    let total_h = h + legend_h;
    let s = map.scale;
    writeln!(out, r#"<?xml version="1.0" encoding="UTF-8"?>"#)?;
    writeln!(
        out,
        r#"<svg xmlns="http://www.w3.org/2000/svg" version="1.1" width="{w}" height="{total_h}" viewBox="0 0 {w} {total_h}">"#
    )?;
    writeln!(out, "<title>{}</title>", escape(&map.title))?;
    writeln!(out, r#"<g id="samples" shape-rendering="crispEdges">"#)?;
    let mut buf = String::new();
    for (j, row) in map.fill.chunks_exact(map.width as usize).enumerate() {
        buf.clear();
        let mut start = 0;
        while start < row.len() {
            let end = start
                + row[start..]
                    .iter()
                    .take_while(|c| **c == row[start])
                    .count();
            let _ = writeln!(
                buf,
                r#"<rect x="{}" y="{}" width="{}" height="{s}" fill="{}"/>"#,
                start as u32 * s,
                j as u32 * s,
                (end - start) as u32 * s,
                hex(row[start])
            );
            start = end;
        }
        out.write_all(buf.as_bytes())?;
    }
    writeln!(out, "</g>")?;
    writeln!(
        out,
        r#"<g id="contours" fill="none" stroke-linejoin="round">"#
    )?;
    for line in map.lines.iter().filter(|l| l.points.len() >= 2) {
        buf.clear();
        for (k, p) in line.points.iter().enumerate() {
            let [x, y] = map.to_pixel(*p);
            let _ = write!(buf, "{}{x:.2} {y:.2}", if k == 0 { "M" } else { " L" });
        }
        if line.closed {
            buf.push_str(" Z");
        }
        writeln!(
            out,
            r#"<path d="{buf}" stroke="{}" stroke-width="{}"/>"#,
            hex(line.color),
            line.width
        )?;
    }
    writeln!(out, "</g>")?;
    if !map.legend.is_empty() {
        writeln!(
            out,
            r#"<g id="legend" font-family="sans-serif" font-size="12">"#
        )?;
        for (k, (name, color)) in map.legend.iter().enumerate() {
            let y = h + k as u32 * LEGEND_ROW;
            writeln!(
                out,
                r#"<rect x="2" y="{}" width="12" height="12" fill="{}" stroke="black"/><text x="18" y="{}">{}</text>"#,
                y + 2,
                hex(*color),
                y + 13,
                escape(name)
            )?;
        }
        writeln!(out, "</g>")?;
    }
    writeln!(out, "</svg>")?;
    out.flush()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escapes_markup() {
        assert_eq!(escape("a<b & \"c\"\u{1}"), "a&lt;b &amp; &quot;c&quot; ");
    }
}
