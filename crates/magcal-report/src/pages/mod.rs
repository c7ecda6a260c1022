//! Self-contained HTML pages of a result (`magcal report`): one file that opens offline, with
//! plotly.js embedded (compressed; nothing is fetched), 3D views a person rotates and
//! hovers, and the result's numbers in tables.
//!
//! A page is a list of [`Block`]s rendered by one askama template (`templates/page.html`), which
//! escapes every text.
//!
//! # A page from someone else's set
//! A page is meant to be shared, and a set can come from anyone: nothing of it may run, fetch or
//! read. Its `Content-Security-Policy` lets no script run but the one the page carries (the loader,
//! named by its SHA-256, which unpacks and runs plotly.js from the binary's own block and draws
//! the figures), loads nothing from anywhere (images only as
//! `data:`), and so blocks every inline event handler. Text reaches the page only escaped: by the
//! template in the markup, as `\u003c` and the like in the JSON blocks (so that no `</script`,
//! `<!--` or `<script` in a string ends or turns a block), and as entities in what plotly shows
//! (its labels take markup such as `<span style>`, which must stay text). Static figures are
//! SVG drawn by magcal from the set's sealed files and shown as `<img>` (`data:` URIs run no
//! script), never inlined. A number in a table keeps its full value in the cell's `data-value`, and
//! the page carries the figures it was made from in `<script id="magcal-data"
//! type="application/json">`, so that a test can hold what is shown against the result's own
//! files. What is drawn may be thinned ([`thin`]) and rounded ([`drawn`]); what is computed and
//! tabled never is, and the page says so where it thins.

pub mod attitudes;
pub mod calibration;
pub mod evaluate;
pub mod next;
pub mod plan;
pub mod replay;
pub mod run;
pub mod sphere;

use std::path::Path;

use anyhow::{Context, Result, bail};
use askama::Template;
use plotly::Plot;
use plotly::configuration::Configuration;
use serde_json::Value;

use crate::manifest::SetKind;

/// One part of a page, in order.
#[derive(Debug, Clone)]
pub enum Block {
    /// A section heading.
    Heading(String),
    /// A paragraph.
    Text(String),
    /// A paragraph in small grey type (how a figure was drawn, what was thinned).
    Note(String),
    /// The result's verdict, green when it is a result to use.
    Verdict { good: bool, text: String },
    /// A table.
    Table(Table),
    /// An interactive plotly figure: its div and script, the height in pixels, a caption.
    Plot {
        id: String,
        html: String,
        height: u32,
        caption: String,
    },
    /// A static figure with a caption: `svg` is the drawing in base64, shown as a `data:` image.
    Image { id: String, svg: String, caption: String },
}

/// A table with an id (the tests find it by it), a caption, a header and rows.
#[derive(Debug, Clone, Default)]
pub struct Table {
    pub id: String,
    pub caption: String,
    pub header: Vec<String>,
    pub rows: Vec<Vec<Cell>>,
}

/// A table cell: its text, and for a number its full value.
#[derive(Debug, Clone, PartialEq)]
pub struct Cell {
    pub text: String,
    pub value: Option<f64>,
}

impl Cell {
    /// A cell of text.
    pub fn text(text: impl Into<String>) -> Self {
        Self {
            text: text.into(),
            value: None,
        }
    }

    /// A number shown with `digits` significant digits, its full value kept; a value that is
    /// not finite is shown as a dash and keeps no value.
    pub fn number(value: f64, digits: usize) -> Self {
        if !value.is_finite() {
            return Self::text("-");
        }
        Self {
            text: significant(value, digits),
            value: Some(value),
        }
    }

    /// A count, shown whole.
    pub fn count(value: usize) -> Self {
        Self {
            text: value.to_string(),
            value: Some(value as f64),
        }
    }

    /// A number, or a dash where there is none.
    pub fn maybe(value: Option<f64>, digits: usize) -> Self {
        value.map_or_else(|| Self::text("-"), |v| Self::number(v, digits))
    }
}

/// `value` with `digits` significant digits (at least 1), in plain notation for magnitudes from
/// 1e-4 to 1e9, else in scientific notation.
pub fn significant(value: f64, digits: usize) -> String {
    let digits = digits.max(1);
    if value == 0.0 {
        return format!("{:.*}", digits.saturating_sub(1), 0.0);
    }
    let magnitude = value.abs().log10().floor() as i32;
    if !(-4..9).contains(&magnitude) {
        return format!("{:.*e}", digits - 1, value);
    }
    let decimals = (digits as i32 - 1 - magnitude).max(0) as usize;
    format!("{value:.decimals$}")
}

/// A page under construction.
#[derive(Debug, Clone)]
pub struct Page {
    title: String,
    subtitle: String,
    blocks: Vec<Block>,
    data: serde_json::Map<String, Value>,
}

#[derive(Template)]
#[template(path = "page.html")]
struct PageTemplate<'a> {
    version: &'a str,
    policy: &'a str,
    title: &'a str,
    subtitle: &'a str,
    blocks: &'a [Block],
    plotly_packed: &'a str,
    loader_js: &'a str,
    /// The data block's JSON, escaped for a script element ([`script_json`]).
    data: &'a str,
}

/// The script that unpacks plotly.js ([`plotly_packed`]) and draws each figure from its JSON
/// block as it comes near the view.
const LOADER_JS: &str = include_str!("../../templates/loader.js");

/// [`PLOTLY_JS`] as a page carries it: zlib-compressed (what the browser's
/// `DecompressionStream("deflate")` reads) and in base64, 0.66 MB instead of 1.49. The loader
/// unpacks it and runs it with `eval`, which the policy allows for plotly.js's own use; it is
/// the binary's constant, and nothing of a result set reaches it.
pub fn plotly_packed() -> &'static str {
    use base64::Engine;
    use std::io::Write;
    static PACKED: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    PACKED.get_or_init(|| {
        let mut zlib = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::best());
        zlib.write_all(PLOTLY_JS.as_bytes()).expect("writes to memory");
        base64::engine::general_purpose::STANDARD.encode(zlib.finish().expect("writes to memory"))
    })
}

/// `plot` as plotly's JSON, with the pages' configuration: the modebar without the plotly logo,
/// the figure's size following the window.
pub fn figure_json(mut plot: Plot) -> Value {
    plot.set_configuration(Configuration::new().display_logo(false).responsive(true));
    serde_json::from_str(&plot.to_json()).expect("plotly writes JSON")
}

/// The page's Content-Security-Policy: no source of anything but the page itself, its
/// script by hash (which also forbids every inline event handler and `javascript:` URL), inline
/// styles (plotly sets them), and images and fonts as `data:` only.
fn policy(scripts: &[&str]) -> String {
    let hashes: Vec<String> = scripts
        .iter()
        .map(|s| format!("'sha256-{}'", magcal_logs::digest::sha256_base64(s.as_bytes())))
        .collect();
    format!(
        "default-src 'none'; script-src {} 'unsafe-eval'; style-src 'unsafe-inline'; img-src data: blob:; font-src data:; connect-src 'none'; worker-src blob:; base-uri 'none'; form-action 'none'",
        hashes.join(" ")
    )
}

/// `value` as JSON text that a `<script type="application/json">` element holds whole: `<`, `>`
/// and `&` as `\u003c`, `\u003e`, `\u0026` (they occur only within strings, where the escape is
/// the same text), so that no `</script`, `<!--` or `<script` ends the element or turns the HTML
/// parser's script-data states; U+2028 and U+2029 escaped too.
pub fn script_json(value: &Value) -> String {
    let text = serde_json::to_string(value).expect("a JSON value serialises");
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '<' => out.push_str("\\u003c"),
            '>' => out.push_str("\\u003e"),
            '&' => out.push_str("\\u0026"),
            '\u{2028}' => out.push_str("\\u2028"),
            '\u{2029}' => out.push_str("\\u2029"),
            c => out.push(c),
        }
    }
    out
}

/// `value` with every string made plain text for plotly, whose labels, titles and hover take a
/// markup of their own (`<b>`, `<a href>`, `<span style>`): `&`, `<` and `>` as the entities
/// plotly shows as those characters. magcal's figures use no markup.
fn plotly_text(value: &mut Value) {
    match value {
        Value::String(s) if s.contains(['&', '<', '>']) => {
            *s = s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;");
        }
        Value::Array(items) => items.iter_mut().for_each(plotly_text),
        Value::Object(map) => map.values_mut().for_each(plotly_text),
        _ => {}
    }
}

/// `value` with every string made plain text for a 3D scene, whose axis titles are drawn in
/// WebGL without reading entities: `<`, `>` and `&` as their full-width forms, which read the
/// same and are no markup anywhere.
fn webgl_text(value: &mut Value) {
    match value {
        Value::String(s) if s.contains(['&', '<', '>']) => {
            *s = s
                .replace('&', "\u{ff06}")
                .replace('<', "\u{ff1c}")
                .replace('>', "\u{ff1e}");
        }
        Value::Array(items) => items.iter_mut().for_each(webgl_text),
        Value::Object(map) => map.values_mut().for_each(webgl_text),
        _ => {}
    }
}

impl Page {
    /// An empty page with a title and a line under it (what it shows, from which files).
    pub fn new(title: impl Into<String>, subtitle: impl Into<String>) -> Self {
        Self {
            title: title.into(),
            subtitle: subtitle.into(),
            blocks: Vec::new(),
            data: serde_json::Map::new(),
        }
    }

    /// Adds a block.
    pub fn push(&mut self, block: Block) {
        self.blocks.push(block);
    }

    /// Adds a section heading.
    pub fn heading(&mut self, text: impl Into<String>) {
        self.push(Block::Heading(text.into()));
    }

    /// Adds a paragraph.
    pub fn text(&mut self, text: impl Into<String>) {
        self.push(Block::Text(text.into()));
    }

    /// Adds a note.
    pub fn note(&mut self, text: impl Into<String>) {
        self.push(Block::Note(text.into()));
    }

    /// Adds a table.
    pub fn table(&mut self, table: Table) {
        self.push(Block::Table(table));
    }

    /// Adds a plotly figure as `id` (a DOM id), `height` pixels high, its modebar without the
    /// plotly logo and its size following the window.
    pub fn plot(&mut self, id: &str, plot: Plot, height: u32, caption: impl Into<String>) {
        self.figure(id, figure_json(plot), height, caption);
    }

    /// Adds a figure given as plotly's JSON (as [`figure_json`] writes it, edited where plotly's
    /// typed traces lack an attribute), as [`Page::plot`] does.
    pub fn figure(&mut self, id: &str, mut figure: Value, height: u32, caption: impl Into<String>) {
        // The figure waits in a JSON block for the page's loader (templates/loader.js), which
        // draws it when it comes near the screen: a page of many WebGL views opens at once
        // instead of building every view before it shows anything.
        for trace in figure["data"].as_array().into_iter().flatten() {
            let kind = trace["type"].as_str().unwrap_or("scatter");
            assert!(
                TRACE_TYPES.contains(&kind),
                "{id}: a {kind} trace, which the pages' plotly.js does not hold (scripts/plotly-bundle/index.js)"
            );
        }
        if let Some(layout) = figure.get_mut("layout").and_then(Value::as_object_mut) {
            layout
                .iter_mut()
                .filter(|(key, _)| key.starts_with("scene"))
                .for_each(|(_, scene)| webgl_text(scene));
        }
        plotly_text(&mut figure);
        let figure = script_json(&figure);
        let html = format!(
            "<div id=\"{id}\" class=\"plotly-graph-div\" style=\"height:100%; width:100%;\"></div>\n<script type=\"application/json\" class=\"magcal-figure\" data-for=\"{id}\">{figure}</script>"
        );
        self.push(Block::Plot {
            id: id.to_string(),
            html,
            height,
            caption: caption.into(),
        });
    }

    /// Records `value` under `key` in the page's data block.
    pub fn data(&mut self, key: &str, value: Value) {
        self.data.insert(key.to_string(), value);
    }

    /// The page as one HTML document.
    ///
    /// # Errors
    /// A template that fails to render (a bug).
    pub fn render(&self) -> Result<String> {
        let data = script_json(&Value::Object(self.data.clone()));
        let page = PageTemplate {
            version: env!("CARGO_PKG_VERSION"),
            policy: &policy(&[LOADER_JS]),
            title: &self.title,
            subtitle: &self.subtitle,
            blocks: &self.blocks,
            plotly_packed: plotly_packed(),
            loader_js: LOADER_JS,
            data: &data,
        };
        page.render().context("the report page does not render")
    }
}

/// plotly.js with only the trace types the pages draw ([`TRACE_TYPES`]): plotly.js's core and
/// those traces, bundled and minified by `scripts/plotly-bundle.sh` from the plotly.js release the
/// `plotly` crate was written for (its licence beside it), a third of the whole library.
pub const PLOTLY_JS: &str = include_str!("../../assets/plotly-custom.min.js");

/// The trace types [`PLOTLY_JS`] registers: a figure of any other would draw nothing.
pub const TRACE_TYPES: &[&str] = &["bar", "box", "heatmap", "mesh3d", "scatter", "scatter3d"];

/// At most `max` indices of `0..n`, evenly spaced, first included: the readings a figure draws.
pub fn thin(n: usize, max: usize) -> Vec<usize> {
    if n <= max {
        return (0..n).collect();
    }
    (0..max).map(|k| k * n / max).collect()
}

/// The note a thinned figure carries: how many of how many readings it draws.
pub fn thinned_note(what: &str, drawn: usize, of: usize) -> Option<String> {
    (drawn < of).then(|| {
        format!("{what}: {drawn} of the {of} readings drawn, evenly through the log; every number on this page is computed from all {of}.")
    })
}

/// A coordinate as drawn: 5 significant digits, which a figure cannot tell from more and which
/// keeps a page of many points small.
pub fn drawn(value: f64) -> f64 {
    if value == 0.0 || !value.is_finite() {
        return value;
    }
    let scale = 10f64.powi(4 - value.abs().log10().floor() as i32);
    (value * scale).round() / scale
}

/// The bytes of the set's file `name`, after checking that they are the ones its manifest
/// recorded (`recorded`), so that a page never shows a file edited after `command` wrote the set;
/// with the path, as messages name it.
///
/// # Errors
/// A manifest that records no hash for the file, a file that is not a plain member of the set,
/// or one whose bytes changed, named.
pub(crate) fn sealed_bytes(
    dir: &Path,
    name: &str,
    recorded: Option<&String>,
    command: &str,
) -> Result<(Vec<u8>, String)> {
    let want = recorded_hash(dir, name, recorded, command)?;
    let member = magcal_logs::limits::set_member(dir, name)?;
    let bytes = magcal_logs::limits::read_bounded(&member, magcal_logs::limits::max_result_file_bytes())?;
    let shown = member.display().to_string();
    if magcal_logs::digest::sha256_hex(&bytes) != *want {
        bail!(edited(&shown, command));
    }
    Ok((bytes, shown))
}

/// The rows of the set's CSV file `name`, read one at a time and handed to `each`, in the memory
/// of one row however long the file; checked as [`sealed_bytes`] checks a file, in the same pass:
/// a file whose SHA-256 is not `recorded` is named as edited, whether or not its rows parse.
/// Returns the number of rows and the path as messages name it.
///
/// # Errors
/// As [`sealed_bytes`], then a row that does not parse (as [`crate::rows::parse_csv`] says it)
/// or an error of `each`.
pub(crate) fn sealed_rows<T: serde::de::DeserializeOwned>(
    dir: &Path,
    name: &str,
    recorded: Option<&String>,
    command: &str,
    each: impl FnMut(T) -> Result<()>,
) -> Result<(usize, String)> {
    let want = recorded_hash(dir, name, recorded, command)?;
    let member = magcal_logs::limits::set_member(dir, name)?;
    let shown = member.display().to_string();
    let file = std::fs::File::open(&member).with_context(|| format!("{shown}: cannot read"))?;
    let mut input = magcal_logs::digest::Hashing::new(file);
    let rows = crate::rows::for_each_csv_row(&mut input, &shown, each);
    // The rest of the file, which a row that failed left unread, completes the hash.
    std::io::copy(&mut input, &mut std::io::sink()).with_context(|| format!("{shown}: cannot read"))?;
    if input.hex() != *want {
        bail!(edited(&shown, command));
    }
    Ok((rows?, shown))
}

/// The SHA-256 the manifest records for `name`.
fn recorded_hash<'a>(dir: &Path, name: &str, recorded: Option<&'a String>, command: &str) -> Result<&'a String> {
    recorded.with_context(|| {
        format!(
            "{}: records no {name}, which a {command} set holds",
            dir.join("manifest.json").display()
        )
    })
}

/// What a page says of a set's file whose bytes are not those its manifest recorded.
fn edited(shown: &str, command: &str) -> String {
    format!(
        "{shown}: edited since {command} wrote it (its SHA-256 is not the one manifest.json records); run {command} again"
    )
}

/// What a report is made from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Source {
    /// A `calibrate --out` set.
    Calibration,
    /// A `replay` set.
    Replay,
    /// A `design` or `run` set.
    Run,
}

impl Source {
    /// The kind of result at `path`.
    ///
    /// # Errors
    /// A path that holds no result magcal can draw.
    pub fn of(path: &Path) -> Result<Self> {
        if path.is_dir() {
            return match SetKind::of(path)? {
                Some(SetKind::Calibration) => Ok(Self::Calibration),
                Some(SetKind::Replay) => Ok(Self::Replay),
                Some(SetKind::Run) => Ok(Self::Run),
                None if path.join("manifest.json").exists() => bail!(
                    "{}: not a magcal manifest (unreadable, not JSON, or not one magcal wrote)",
                    path.join("manifest.json").display()
                ),
                None => bail!("{}: not a magcal result set (no manifest.json)", path.display()),
            };
        }
        if !path.exists() {
            bail!("{}: no such directory", path.display());
        }
        bail!("{}: not a magcal result set directory", path.display())
    }
}

/// The page of the result at `path`.
///
/// # Errors
/// A result that cannot be read, or whose files disagree.
pub fn page_of(path: &Path) -> Result<Page> {
    match Source::of(path)? {
        Source::Calibration => calibration::page(path),
        Source::Replay => replay::page(path),
        Source::Run => run::page(path),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_show_their_significant_digits() {
        assert_eq!(significant(4.56789, 3), "4.57");
        assert_eq!(significant(-0.000123456, 3), "-0.000123");
        assert_eq!(significant(12345.6, 3), "12346");
        assert_eq!(significant(0.0, 3), "0.00");
        assert_eq!(significant(1.5e-7, 2), "1.5e-7");
        assert_eq!(significant(49_000.0, 4), "49000");
        assert_eq!(Cell::number(f64::NAN, 3), Cell::text("-"));
    }

    #[test]
    fn thinning_keeps_at_most_max_evenly_spaced_readings() {
        assert_eq!(thin(5, 10), vec![0, 1, 2, 3, 4]);
        assert_eq!(thin(10, 5), vec![0, 2, 4, 6, 8]);
        let t = thin(12_001, 4000);
        assert_eq!(t.len(), 4000);
        assert!(t.windows(2).all(|w| w[1] > w[0] && w[1] - w[0] <= 4));
        assert_eq!(drawn(123.456789), 123.46);
        assert_eq!(drawn(-0.000987654321), -0.00098765);
    }

    #[test]
    fn script_json_keeps_every_string_inside_its_element() {
        let v = serde_json::json!({"a": "<!-- <script> </script> & \u{2028}\u{2029}", "<k>": 1});
        let text = script_json(&v);
        assert!(!text.contains(['<', '>', '&', '\u{2028}', '\u{2029}']), "{text}");
        assert_eq!(serde_json::from_str::<Value>(&text).unwrap(), v, "the same JSON");
    }

    #[test]
    fn a_scenes_text_is_plain_without_entities() {
        let mut v = serde_json::json!({"xaxis": {"title": {"text": "x, <b>uT</b> & more"}}, "n": 1});
        webgl_text(&mut v);
        assert_eq!(
            v,
            serde_json::json!({"xaxis": {"title": {"text": "x, \u{ff1c}b\u{ff1e}uT\u{ff1c}/b\u{ff1e} \u{ff06} more"}}, "n": 1})
        );
    }

    #[test]
    fn figure_text_is_plain_for_plotly() {
        let mut v =
            serde_json::json!({"name": "<span style=\"background:url(http://x)\">a & b</span>", "x": [1, "c<d"]});
        plotly_text(&mut v);
        assert_eq!(
            v["name"],
            "&lt;span style=\"background:url(http://x)\"&gt;a &amp; b&lt;/span&gt;"
        );
        assert_eq!(v["x"][1], "c&lt;d");
        assert_eq!(v["x"][0], 1);
    }

    #[test]
    fn the_bundle_is_the_one_its_script_built_and_registers_the_trace_types() {
        let recorded = include_str!("../../assets/plotly-custom.min.js.sha256");
        assert_eq!(
            recorded.split_whitespace().next(),
            Some(magcal_logs::digest::sha256_hex(PLOTLY_JS.as_bytes()).as_str()),
            "assets/plotly-custom.min.js is not what scripts/plotly-bundle.sh built"
        );
        assert!(
            PLOTLY_JS.starts_with("/**\n* plotly.js v3.0.1 "),
            "{}",
            &PLOTLY_JS[..80]
        );
        // Each trace module of plotly.js declares itself so; the bundle holds these and no other.
        let mut registered: Vec<&str> = PLOTLY_JS
            .split("moduleType:\"trace\",name:\"")
            .skip(1)
            .filter_map(|rest| rest.split('"').next())
            .collect();
        registered.sort_unstable();
        assert_eq!(registered, TRACE_TYPES);
        assert!(PLOTLY_JS.len() < 1_600_000, "{} bytes", PLOTLY_JS.len());
    }

    #[test]
    fn the_page_carries_the_bundle_packed_whole() {
        use base64::Engine;
        use std::io::Read;
        let html = Page::new("t", "s").render().unwrap();
        let packed = html
            .split("<script type=\"application/octet-stream\" id=\"magcal-plotly\">")
            .nth(1)
            .and_then(|r| r.split("</script>").next())
            .unwrap();
        let bytes = base64::engine::general_purpose::STANDARD.decode(packed).unwrap();
        let mut unpacked = String::new();
        flate2::read::ZlibDecoder::new(bytes.as_slice())
            .read_to_string(&mut unpacked)
            .unwrap();
        assert_eq!(unpacked, PLOTLY_JS);
        assert!(packed.len() < 700_000, "{} bytes", packed.len());
    }

    #[test]
    #[should_panic(expected = "a pie trace, which the pages' plotly.js does not hold")]
    fn a_figure_of_a_trace_type_the_bundle_lacks_is_a_bug() {
        let mut plot = Plot::new();
        plot.add_trace(plotly::Pie::new(vec![1.0, 2.0]));
        Page::new("t", "s").plot("p", plot, 300, "c");
    }

    #[test]
    fn the_policy_names_the_page_scripts_and_loads_nothing() {
        let mut page = Page::new("t", "s");
        page.text("x");
        let html = page.render().unwrap();
        let policy = html
            .split("http-equiv=\"Content-Security-Policy\" content=\"")
            .nth(1)
            .and_then(|r| r.split('"').next())
            .unwrap();
        let hash = magcal_logs::digest::sha256_base64(LOADER_JS.as_bytes());
        assert!(policy.contains(&format!("'sha256-{hash}'")), "{policy}");
        assert!(html.contains(&format!("<script type=\"text/javascript\">{LOADER_JS}</script>")));
        assert_eq!(policy.matches("'sha256-").count(), 1, "{policy}");
        for part in ["default-src 'none'", "connect-src 'none'", "img-src data: blob:"] {
            assert!(policy.contains(part), "{policy}");
        }
        // No inline script but those named: an event handler or a `javascript:` URL runs nowhere.
        let scripts = policy.split(';').find(|d| d.trim().starts_with("script-src")).unwrap();
        assert!(!scripts.contains("'unsafe-inline'"), "{scripts}");
    }

    #[test]
    fn a_page_escapes_text_and_embeds_plotly_once_and_nothing_remote() {
        let mut page = Page::new("a <b> & \"c\"", "sub");
        page.text("x < y");
        page.table(Table {
            id: "t".into(),
            caption: "cap".into(),
            header: vec!["h".into()],
            rows: vec![vec![Cell::number(1.0 / 3.0, 3)]],
        });
        page.data("k", serde_json::json!({"v": "</script>"}));
        let mut plot = Plot::new();
        plot.add_trace(plotly::Scatter::new(vec![1.0], vec![2.0]).name("</script><b>"));
        page.plot("p", plot, 300, "c");
        let html = page.render().unwrap();
        assert!(
            html.contains("<title>a &#60;b&#62; &#38; &#34;c&#34;</title>"),
            "{}",
            &html[..400]
        );
        assert!(html.contains("<p>x &#60; y</p>"));
        assert!(html.contains("data-value=\"0.3333333333333333\">0.333</td>"));
        assert!(
            !html.contains("\"</script>\""),
            "the data block must not close its script"
        );
        assert_eq!(
            html.matches("<script type=\"text/javascript\">").count(),
            1,
            "the loader of plotly.js and the figures runs; nothing else"
        );
        assert_eq!(
            html.matches("<script").count(),
            4,
            "and plotly.js packed, the data and figure blocks"
        );
        // In the figure, plotly's markup is entities, and those in JSON escapes.
        assert!(
            html.contains(r#""name":"\u0026lt;/script\u0026gt;\u0026lt;b\u0026gt;""#),
            "a figure cannot end its block nor carry plotly markup"
        );
        assert!(!html.contains("<script src"), "no script from elsewhere");
        assert!(!html.contains("<link"), "no stylesheet from elsewhere");
    }
}
