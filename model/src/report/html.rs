//! A self-contained HTML page: headings, paragraphs, tables, and figures embedded in the file
//! (SVG inline, PNG as base64 data), so it opens offline and can be mailed as one file.

use std::fmt::Write as _;
use std::path::Path;

use crate::fsio;
use base64::engine::general_purpose::STANDARD as BASE64;
use base64::Engine as _;

/// An HTML page under construction.
#[derive(Clone, Debug, Default)]
pub struct Page {
    title: String,
    body: String,
}

/// Text with `&`, `<`, `>` and `"` escaped.
pub fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Text as HTML: escaped, with `code` spans (as the command line's messages and notes write
/// them) set as `<code>`; an unpaired backtick stays as it is.
pub fn inline(s: &str) -> String {
    let parts: Vec<&str> = s.split('`').collect();
    let paired = parts.len() % 2 == 1;
    let mut out = String::new();
    for (k, part) in parts.iter().enumerate() {
        match (k % 2, paired || k + 1 < parts.len()) {
            (1, true) => {
                let _ = write!(out, "<code>{}</code>", escape(part));
            }
            (1, false) => {
                out.push('`');
                out += &escape(part);
            }
            _ => out += &escape(part),
        }
    }
    out
}

impl Page {
    pub fn new(title: &str) -> Self {
        Page {
            title: title.to_string(),
            body: String::new(),
        }
    }

    /// A section heading, with an anchor `id`.
    pub fn section(&mut self, id: &str, title: &str) -> &mut Self {
        let _ = writeln!(self.body, "<h2 id=\"{id}\">{}</h2>", escape(title));
        self
    }

    pub fn paragraph(&mut self, text: &str) -> &mut Self {
        let _ = writeln!(self.body, "<p>{}</p>", inline(text));
        self
    }

    /// A table; cells that are numbers are right-aligned.
    pub fn table(&mut self, header: &[&str], rows: &[Vec<String>]) -> &mut Self {
        self.body += "<table>\n<tr>";
        for h in header {
            let _ = write!(self.body, "<th>{}</th>", escape(h));
        }
        self.body += "</tr>\n";
        for row in rows {
            self.body += "<tr>";
            for cell in row {
                let class = if cell.parse::<f64>().is_ok() {
                    " class=\"n\""
                } else {
                    ""
                };
                let _ = write!(self.body, "<td{class}>{}</td>", inline(cell));
            }
            self.body += "</tr>\n";
        }
        self.body += "</table>\n";
        self
    }

    /// Preformatted text.
    pub fn pre(&mut self, text: &str) -> &mut Self {
        let _ = writeln!(self.body, "<pre>{}</pre>", escape(text));
        self
    }

    /// A figure from a file: SVG inline, PNG embedded as base64; a missing file is said so.
    pub fn figure(&mut self, path: &Path, caption: &str) -> &mut Self {
        let content = match path.extension().and_then(|e| e.to_str()) {
            Some("svg") => std::fs::read_to_string(path).ok().map(|svg| {
                // Drop the XML declaration: the SVG is an element of this page.
                match svg.find("<svg") {
                    Some(start) => svg[start..].to_string(),
                    None => svg,
                }
            }),
            Some("png") => std::fs::read(path).ok().map(|bytes| {
                format!(
                    "<img src=\"data:image/png;base64,{}\" alt=\"{}\">",
                    BASE64.encode(&bytes),
                    escape(caption)
                )
            }),
            _ => None,
        };
        let inner = content.unwrap_or_else(|| {
            format!(
                "<p class=\"missing\">(figure {} missing)</p>",
                escape(&path.display().to_string())
            )
        });
        let _ = writeln!(
            self.body,
            "<figure>{inner}<figcaption>{}</figcaption></figure>",
            escape(caption)
        );
        self
    }

    /// The whole page.
    pub fn html(&self) -> String {
        format!(
            "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>{}</title>\n<style>{STYLE}</style>\n</head>\n<body>\n<h1>{}</h1>\n{}</body>\n</html>\n",
            escape(&self.title),
            escape(&self.title),
            self.body
        )
    }

    /// Writes the page atomically.
    ///
    /// # Errors
    /// When the file cannot be written.
    pub fn write(&self, path: &Path) -> std::io::Result<()> {
        fsio::write_bytes(path, self.html().as_bytes())
    }
}

const STYLE: &str = "body{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222;line-height:1.45}\
h1{font-size:1.7em}h2{margin-top:2em;border-bottom:1px solid #ccc;padding-bottom:.2em}\
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:.25em .6em;text-align:left}\
td.n{text-align:right;font-variant-numeric:tabular-nums}th{background:#f3f3f3}\
figure{margin:1em 0}figure svg,figure img{max-width:100%;height:auto;border:1px solid #eee}\
figcaption{font-size:.9em;color:#555}pre{background:#f7f7f7;padding:.6em;overflow-x:auto;font-size:.85em}\
.missing{color:#a00}";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn code_spans_become_code_and_a_lone_backtick_stays() {
        assert_eq!(
            inline("with `handcap synth`'s <three>"),
            "with <code>handcap synth</code>'s &lt;three&gt;"
        );
        assert_eq!(inline("a ` b `c` d"), "a <code> b </code>c` d");
        assert_eq!(inline("plain"), "plain");
    }

    #[test]
    fn text_is_escaped_and_figures_are_embedded() {
        let dir = tempfile::tempdir().unwrap();
        let svg = dir.path().join("a.svg");
        std::fs::write(&svg, "<?xml version=\"1.0\"?>\n<svg width=\"1\"></svg>").unwrap();
        let mut page = Page::new("R&D <report>");
        page.paragraph("x < y")
            .table(&["a", "b"], &[vec!["1".into(), "<2>".into()]])
            .figure(&svg, "an svg")
            .figure(&dir.path().join("none.png"), "gone");
        let html = page.html();
        assert!(html.contains("<title>R&amp;D &lt;report&gt;</title>"));
        assert!(html.contains("<p>x &lt; y</p>"));
        assert!(html.contains("<td class=\"n\">1</td><td>&lt;2&gt;</td>"));
        assert!(html.contains("<figure><svg width=\"1\"></svg>"));
        assert!(!html.contains("<?xml"));
        assert!(html.contains("none.png missing"));
    }
}
