//! A board to print: SVG at true size (millimetre units), the squares with a one-square white
//! margin, a ChArUco board's markers bit by bit where OpenCV's detector expects them, and a
//! caption in the margin saying what the board is.

use std::fmt::Write;

use super::{BoardSpec, CalibError};

/// The page the board needs (mm): the squares and a one-square margin on each side.
pub fn page_mm(board: &BoardSpec) -> [f64; 2] {
    let s = board.square_mm;
    [(board.cols + 3) as f64 * s, (board.rows + 3) as f64 * s]
}

/// The board as an SVG document whose user unit is 1 mm.
///
/// # Errors
/// [`CalibError::OpenCv`] when OpenCV cannot draw a marker.
pub fn svg(board: &BoardSpec) -> Result<String, CalibError> {
    let s = board.square_mm;
    let [w, h] = page_mm(board);
    let caption_y = h - s / 3.0;
    // Board frame (origin at the first inner corner) → page: two squares in.
    let page = |v: f64| v + 2.0 * s;
    let mut out = String::new();
    let (w, h) = (mm(w), mm(h));
    let _ = writeln!(
        out,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}mm" height="{h}mm" viewBox="0 0 {w} {h}" shape-rendering="crispEdges">"#
    );
    let _ = writeln!(out, r#"<rect width="{w}" height="{h}" fill="white"/>"#);
    for y in 0..=board.rows {
        for x in 0..=board.cols {
            if (x + y) % 2 == 0 {
                let _ = writeln!(
                    out,
                    r#"<rect x="{}" y="{}" width="{}" height="{}"/>"#,
                    mm((x + 1) as f64 * s),
                    mm((y + 1) as f64 * s),
                    mm(s),
                    mm(s)
                );
            }
        }
    }
    for marker in board.markers()? {
        let [c0, c1, _, c3] = marker.corners;
        let n = marker.side;
        let (du, dv) = ((c1[0] - c0[0]) / n as f64, (c3[1] - c0[1]) / n as f64);
        // Each row's runs of black bits as one rectangle, whichever way the marker's axes run
        // on the board.
        for row in 0..n {
            let bits = &marker.white[row * n..(row + 1) * n];
            let mut col = 0;
            while col < n {
                if bits[col] {
                    col += 1;
                    continue;
                }
                let run = bits[col..].iter().take_while(|w| !**w).count();
                let (x0, x1) = (c0[0] + col as f64 * du, c0[0] + (col + run) as f64 * du);
                let (y0, y1) = (c0[1] + row as f64 * dv, c0[1] + (row + 1) as f64 * dv);
                let _ = writeln!(
                    out,
                    r#"<rect x="{}" y="{}" width="{}" height="{}"/>"#,
                    mm(page(x0.min(x1))),
                    mm(page(y0.min(y1))),
                    mm((x1 - x0).abs()),
                    mm((y1 - y0).abs())
                );
                col += run;
            }
        }
    }
    let caption = format!(
        "{}: print at 100 %, measure a square",
        board.pattern.kind().options(board, &|v| mm(v))
    );
    let _ = writeln!(
        out,
        r#"<text x="{}" y="{}" font-family="sans-serif" font-size="{}" fill="gray">{caption}</text>"#,
        mm(s),
        mm(caption_y),
        mm((s / 4.0).min(3.5))
    );
    out.push_str("</svg>\n");
    Ok(out)
}

/// A length in mm to a micrometre, without trailing zeros.
fn mm(v: f64) -> String {
    let text = format!("{v:.3}");
    text.trim_end_matches('0').trim_end_matches('.').to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_chessboard_has_its_black_squares_and_true_size() {
        let board = BoardSpec::chessboard(9, 6, 10.0);
        let svg = svg(&board).unwrap();
        assert!(svg.contains(r#"width="120mm" height="90mm""#), "{svg}");
        // 10 × 7 squares, half of them black (35), plus the page.
        assert_eq!(svg.matches("<rect").count(), 36);
    }
}
