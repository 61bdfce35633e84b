//! Text from data files (scene, view, experiment and run names) made safe where it reaches
//! markup: HTML ([`html_text`]) and Markdown table cells and headings ([`markdown_text`]), so a
//! name like `<script>` or one holding `|` or a newline shows as the text it is instead of
//! adding markup, a column or a row.

/// The characters of a name the Markdown shows at most.
const MARKDOWN_CHARS: usize = 200;

/// `s` as HTML text (also safe inside a quoted attribute).
pub fn html_text(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
        .replace('\'', "&#39;")
}

/// `s` as literal Markdown text on one line (a table cell or a heading): HTML's special
/// characters as entities; a cell's `|`, code's backtick, a link's brackets and the backslash
/// escaped with a backslash; line breaks and other control characters as spaces; cut to 200
/// characters. (Emphasis characters stay: they can only restyle the name itself.)
pub fn markdown_text(s: &str) -> String {
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i == MARKDOWN_CHARS {
            out.push('…');
            break;
        }
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '\\' | '`' | '[' | ']' | '|' => {
                out.push('\\');
                out.push(c);
            }
            c if c.is_control() => out.push(' '),
            c => out.push(c),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_stay_text() {
        assert_eq!(
            html_text("<svg onload=\"x\">&'"),
            "&lt;svg onload=&quot;x&quot;&gt;&amp;&#39;"
        );
        let md = markdown_text("<script>a|b\n| fake | row |");
        assert!(!md.contains('<') && !md.contains('\n'), "{md}");
        // every `|` escaped: the cell stays one cell
        assert_eq!(md.matches('|').count(), md.matches("\\|").count());
        assert_eq!(markdown_text("view_1 (a)"), "view_1 (a)");
        assert_eq!(markdown_text("[x](javascript:y)"), "\\[x\\](javascript:y)");
        assert_eq!(markdown_text(&"x".repeat(1000)).chars().count(), 201);
    }
}
