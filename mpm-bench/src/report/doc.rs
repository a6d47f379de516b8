//! The report document model: sections of paragraphs, lists, tables and SVG figures, and its
//! three renderings (self-contained HTML, Markdown, JSON), so that every report page says the
//! same thing in each format from one code path.

use serde::Serialize;
use std::fmt::Write as _;

/// One block of a section.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "kind", content = "content", rename_all = "snake_case")]
pub enum Block {
    /// A paragraph of plain text.
    Para(String),
    /// A bulleted list of plain-text items.
    List(Vec<String>),
    /// A table: a caption (may be empty), the head and the rows (plain text cells).
    Table {
        /// Caption above the table.
        caption: String,
        /// Column heads.
        head: Vec<String>,
        /// Rows, each as long as `head`.
        rows: Vec<Vec<String>>,
    },
    /// A figure: its title, the file its SVG is written to beside the Markdown, and the SVG.
    Figure {
        /// Title (alt text).
        title: String,
        /// File name of the SVG beside `report.md`.
        file: String,
        /// The SVG document itself (inlined into the HTML; not in the JSON).
        #[serde(skip)]
        svg: String,
    },
}

/// A titled section with an anchor id.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Section {
    /// Anchor (`id` attribute in the HTML).
    pub id: String,
    /// Heading.
    pub title: String,
    /// Content.
    pub blocks: Vec<Block>,
}

/// A whole report page.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Doc {
    /// Page title.
    pub title: String,
    /// Sections in order.
    pub sections: Vec<Section>,
}

/// Escape text for HTML element content and attribute values.
pub fn html_escape(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            '\'' => o.push_str("&#39;"),
            _ => o.push(c),
        }
    }
    o
}

/// Escape a Markdown table cell (pipes and line breaks).
fn md_cell(s: &str) -> String {
    s.replace('|', "\\|").replace('\n', " ")
}

const CSS: &str =
    "body{font-family:system-ui,sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222;line-height:1.4}\
table{border-collapse:collapse;margin:0.5em 0 1.5em;font-size:0.9em}\
th,td{border:1px solid #ccc;padding:0.25em 0.6em;text-align:left;vertical-align:top}\
th{background:#f0f0f0}tr:nth-child(even) td{background:#fafafa}\
figure{margin:1em 0}figure svg{max-width:100%;height:auto}figcaption{font-size:0.9em;color:#555}\
nav ul{columns:2}caption{text-align:left;font-weight:bold;padding:0.3em 0}\
h2{border-bottom:2px solid #ddd;padding-bottom:0.2em;margin-top:2em}";

impl Doc {
    /// The self-contained HTML page: inline CSS and SVG, no scripts, no external resources.
    pub fn to_html(&self) -> String {
        let mut s = String::from("<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n");
        let _ = writeln!(s, "<title>{}</title>\n<style>{CSS}</style>\n</head>\n<body>", html_escape(&self.title));
        let _ = writeln!(s, "<h1>{}</h1>\n<nav><ul>", html_escape(&self.title));
        for sec in &self.sections {
            let _ = writeln!(s, "<li><a href=\"#{}\">{}</a></li>", html_escape(&sec.id), html_escape(&sec.title));
        }
        s.push_str("</ul></nav>\n");
        for sec in &self.sections {
            let _ = writeln!(s, "<section id=\"{}\">\n<h2>{}</h2>", html_escape(&sec.id), html_escape(&sec.title));
            for b in &sec.blocks {
                html_block(&mut s, b);
            }
            s.push_str("</section>\n");
        }
        s.push_str("</body>\n</html>\n");
        s
    }

    /// The Markdown rendering; figures are referenced by their SVG file names.
    pub fn to_markdown(&self) -> String {
        let mut s = format!("# {}\n", self.title);
        for sec in &self.sections {
            let _ = writeln!(s, "\n## {}\n", sec.title);
            for b in &sec.blocks {
                md_block(&mut s, b);
            }
        }
        s
    }

    /// Every figure: (file name, SVG text).
    pub fn figures(&self) -> Vec<(&str, &str)> {
        self.sections
            .iter()
            .flat_map(|s| &s.blocks)
            .filter_map(|b| match b {
                Block::Figure { file, svg, .. } => Some((file.as_str(), svg.as_str())),
                _ => None,
            })
            .collect()
    }
}

fn html_block(s: &mut String, b: &Block) {
    match b {
        Block::Para(t) => {
            let _ = writeln!(s, "<p>{}</p>", html_escape(t));
        }
        Block::List(items) => {
            s.push_str("<ul>\n");
            for i in items {
                let _ = writeln!(s, "<li>{}</li>", html_escape(i));
            }
            s.push_str("</ul>\n");
        }
        Block::Table { caption, head, rows } => {
            s.push_str("<table>\n");
            if !caption.is_empty() {
                let _ = writeln!(s, "<caption>{}</caption>", html_escape(caption));
            }
            s.push_str("<thead><tr>");
            for h in head {
                let _ = write!(s, "<th>{}</th>", html_escape(h));
            }
            s.push_str("</tr></thead>\n<tbody>\n");
            for r in rows {
                s.push_str("<tr>");
                for c in r {
                    let _ = write!(s, "<td>{}</td>", html_escape(c));
                }
                s.push_str("</tr>\n");
            }
            s.push_str("</tbody>\n</table>\n");
        }
        Block::Figure { title, svg, .. } => {
            // The SVG comes from plotters' SVG backend (it escapes its own text).
            let body = svg.find("<svg").map_or(svg.as_str(), |i| &svg[i..]);
            let _ = writeln!(s, "<figure>\n{body}\n<figcaption>{}</figcaption>\n</figure>", html_escape(title));
        }
    }
}

fn md_block(s: &mut String, b: &Block) {
    match b {
        Block::Para(t) => {
            let _ = writeln!(s, "{t}\n");
        }
        Block::List(items) => {
            for i in items {
                let _ = writeln!(s, "- {i}");
            }
            s.push('\n');
        }
        Block::Table { caption, head, rows } => {
            if !caption.is_empty() {
                let _ = writeln!(s, "**{caption}**\n");
            }
            let _ = writeln!(s, "| {} |", head.iter().map(|h| md_cell(h)).collect::<Vec<_>>().join(" | "));
            let _ = writeln!(s, "|{}", "---|".repeat(head.len()));
            for r in rows {
                let _ = writeln!(s, "| {} |", r.iter().map(|c| md_cell(c)).collect::<Vec<_>>().join(" | "));
            }
            s.push('\n');
        }
        Block::Figure { title, file, .. } => {
            let _ = writeln!(s, "![{title}]({file})\n");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn html_escapes_every_text_and_md_escapes_pipes() {
        let d = Doc {
            title: "a<b".into(),
            sections: vec![Section {
                id: "x".into(),
                title: "&".into(),
                blocks: vec![
                    Block::Para("<script>".into()),
                    Block::Table { caption: String::new(), head: vec!["h\"".into()], rows: vec![vec!["a|b".into()]] },
                ],
            }],
        };
        let h = d.to_html();
        assert!(h.contains("a&lt;b") && h.contains("&amp;") && h.contains("&lt;script&gt;") && h.contains("h&quot;"));
        assert!(!h.contains("<script>"));
        assert!(d.to_markdown().contains("a\\|b"));
    }
}
