//! `report.html`: one self-contained file per campaign, printable to PDF from a browser. Every
//! plot is embedded (PNG data URIs), nothing is fetched: the file can be mailed or archived
//! alone. Content: state and errors, timings, the summary table, the ISO 230-2 figures and chart
//! of each axis with their source, every component plot, the rig's identification, versions and
//! the campaign file as run.
use base64::Engine as _;

use super::AxisIso230;

/// What the report shows; the caller gathers it from the campaign, its events and its results.
#[derive(Debug, Clone, Default)]
pub struct HtmlReport<'a> {
    pub id: i64,
    pub name: &'a str,
    /// `done`, `failed`, ...
    pub state: &'a str,
    pub errors: &'a [String],
    /// Identity of the store the campaign is in.
    pub store_id: &'a str,
    /// (label, value) rows: created, started, finished, wall time, per-phase times.
    pub timings: Vec<(String, String)>,
    /// The summary table (`summary.txt`).
    pub table: &'a str,
    pub iso: &'a [AxisIso230],
    /// Result files (name, content type, bytes): `plots/*.png` are embedded.
    pub files: &'a [(String, String, Vec<u8>)],
    /// (device, identification) rows: the rig's description and each axis's `*IDN?` reply.
    pub rig: Vec<(String, String)>,
    /// The campaign file's text as run, and where it came from.
    pub campaign_text: &'a str,
    pub campaign_origin: &'a str,
}

/// Text made safe for HTML element content and attribute values.
pub fn esc(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for ch in s.chars() {
        match ch {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            '\'' => o.push_str("&#39;"),
            c => o.push(c),
        }
    }
    o
}

const STYLE: &str = "body{font-family:sans-serif;max-width:1100px;margin:1.5em auto;padding:0 1em;color:#222}\
h1{font-size:1.5em}h2{font-size:1.2em;border-bottom:1px solid #ccc;margin-top:1.6em}\
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ccc;padding:.2em .6em;text-align:left}\
th{background:#f3f3f3}td.num{text-align:right;font-variant-numeric:tabular-nums}\
pre{background:#f7f7f7;padding:.6em;overflow-x:auto;font-size:.85em;white-space:pre-wrap}\
img{max-width:100%;height:auto;display:block;margin:.5em 0}.err{color:#b00020}.note{color:#555;font-size:.9em}\
figure{margin:0 0 1em 0;break-inside:avoid}\
@media print{body{max-width:none;margin:0}h2{break-after:avoid}pre{white-space:pre-wrap}}";

fn um(v: Option<f64>) -> String {
    match v {
        Some(v) if v.is_finite() => format!("{v:.3}"),
        _ => "n/a".into(),
    }
}

fn png_uri(bytes: &[u8]) -> String {
    format!(
        "data:image/png;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(bytes)
    )
}

/// The report as one HTML document.
pub fn report_html(r: &HtmlReport<'_>) -> String {
    let mut h = String::new();
    let title = format!("csmetro campaign {} — {}", r.id, r.name);
    h.push_str(&format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{}</title><style>{STYLE}</style></head><body>\n",
        esc(&title)
    ));
    h.push_str(&format!("<h1>{}</h1>\n", esc(&title)));
    h.push_str(&format!(
        "<p>State: <b>{}</b>. Store {}, campaign {}. Units: positions and errors in µm (error = measured − target), times in s.</p>\n",
        esc(r.state),
        esc(r.store_id),
        r.id
    ));
    for e in r.errors {
        h.push_str(&format!("<p class=\"err\">error: {}</p>\n", esc(e)));
    }

    h.push_str("<h2>Timings</h2>\n<table>\n");
    for (k, v) in &r.timings {
        h.push_str(&format!(
            "<tr><th>{}</th><td class=\"num\">{}</td></tr>\n",
            esc(k),
            esc(v)
        ));
    }
    h.push_str("</table>\n<h2>Summary</h2>\n");
    h.push_str(&format!("<pre>{}</pre>\n", esc(r.table)));

    h.push_str("<h2>ISO 230-2</h2>\n");
    if r.iso.is_empty() {
        h.push_str("<p>No driving-direction component: no ISO 230-2 figures.</p>\n");
    }
    for f in r.iso {
        let s = f.reported();
        h.push_str(&format!(
            "<h3>{} axis — {}</h3>\n<table><tr><th>figure</th><th>bidirectional / µm</th><th>↑ forward / µm</th><th>↓ backward / µm</th></tr>\n",
            esc(&f.axis.to_uppercase()),
            esc(&f.source_label)
        ));
        for (name, bi, up, down) in [
            ("A accuracy", Some(s.a_um), s.a_up_um, s.a_down_um),
            (
                "E systematic deviation",
                Some(s.e_um),
                s.e_up_um,
                s.e_down_um,
            ),
            ("R repeatability", s.r_um, s.r_up_um, s.r_down_um),
            ("B reversal value", s.b_um, None, None),
            ("B̄ mean reversal value", s.b_mean_um, None, None),
            (
                "M range of mean bidirectional deviation",
                s.m_um,
                None,
                None,
            ),
        ] {
            h.push_str(&format!(
                "<tr><td>{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td></tr>\n",
                esc(name),
                um(bi),
                um(up),
                um(down)
            ));
        }
        h.push_str(&format!(
            "</table>\n<p class=\"note\">{} targets, at least {} approach(es) per target and direction.</p>\n",
            s.targets, s.min_approaches
        ));
        if let Some(u) = &f.uncertainty {
            h.push_str(&budget_table(u));
        }
        for n in &f.notes {
            h.push_str(&format!("<p class=\"note\">{}</p>\n", esc(n)));
        }
        let chart = format!("plots/iso230_{}.png", f.axis);
        if let Some((_, _, b)) = r.files.iter().find(|(n, _, _)| *n == chart) {
            h.push_str(&format!(
                "<figure><img alt=\"{}\" src=\"{}\"></figure>\n",
                esc(&chart),
                png_uri(b)
            ));
        }
    }

    h.push_str("<h2>Components</h2>\n");
    for (name, _, bytes) in r.files.iter().filter(|(n, ct, _)| {
        n.starts_with("plots/") && !n.starts_with("plots/iso230_") && ct == "image/png"
    }) {
        h.push_str(&format!(
            "<figure><img alt=\"{}\" src=\"{}\"></figure>\n",
            esc(name),
            png_uri(bytes)
        ));
    }

    h.push_str("<h2>Rig</h2>\n<table>\n");
    for (k, v) in &r.rig {
        h.push_str(&format!(
            "<tr><th>{}</th><td>{}</td></tr>\n",
            esc(k),
            esc(v)
        ));
    }
    h.push_str("</table>\n<h2>Versions</h2>\n<table>\n");
    h.push_str(&format!(
        "<tr><th>csmetro</th><td>{}</td></tr>\n<tr><th>store schema</th><td>{}</td></tr>\n</table>\n",
        esc(env!("CARGO_PKG_VERSION")),
        crate::store::SCHEMA_VERSION
    ));
    h.push_str(&format!(
        "<h2>Campaign file</h2>\n<p class=\"note\">{}</p>\n<pre>{}</pre>\n",
        esc(r.campaign_origin),
        esc(r.campaign_text)
    ));
    h.push_str("<h2>Files</h2>\n<ul>\n");
    for (name, _, bytes) in r.files {
        h.push_str(&format!(
            "<li><a href=\"{}\">{}</a> ({} bytes)</li>\n",
            esc(name),
            esc(name),
            bytes.len()
        ));
    }
    h.push_str("</ul>\n</body></html>\n");
    h
}

/// The ISO 230-2 figures with their expanded uncertainty and the budget behind each.
fn budget_table(u: &crate::iso_uncertainty::IsoUncertainty) -> String {
    let sources = ["data", "pitch", "thermal", "misalignment"];
    let mut h = format!(
        "<h4>Uncertainty (k = {}), budget of standard uncertainties over {:.0} µm</h4>\n<table><tr><th>figure</th><th>value ± U / µm</th>",
        u.e.k, u.length_um
    );
    for s in sources {
        h.push_str(&format!("<th>u {s} / µm</th>"));
    }
    h.push_str("<th>u combined / µm</th></tr>\n");
    for (name, b) in [
        ("A", Some(&u.a)),
        ("B", u.b.as_ref()),
        ("E", Some(&u.e)),
        ("M", u.m.as_ref()),
        ("R", u.r.as_ref()),
    ] {
        let Some(b) = b else { continue };
        h.push_str(&format!(
            "<tr><td>{name}</td><td class=\"num\">{}</td>",
            esc(&b.display())
        ));
        for s in sources {
            let v = b.contributions.iter().find(|c| c.source == s);
            h.push_str(&format!(
                "<td class=\"num\">{}</td>",
                v.map_or("—".to_string(), |c| format!("{:.4}", c.u_um))
            ));
        }
        h.push_str(&format!("<td class=\"num\">{:.4}</td></tr>\n", b.u_um));
    }
    h.push_str("</table>\n");
    for n in &u.notes {
        h.push_str(&format!("<p class=\"note\">{}</p>\n", esc(n)));
    }
    h
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_report_is_self_contained_and_escapes_what_it_shows() {
        let png = vec![0x89, b'P', b'N', b'G', 1, 2, 3];
        let files = vec![
            (
                "plots/ef_xx.png".to_string(),
                "image/png".to_string(),
                png.clone(),
            ),
            (
                "plots/ef_xx.svg".to_string(),
                "image/svg+xml".to_string(),
                b"<svg/>".to_vec(),
            ),
        ];
        let errors = vec!["a <b> & c".to_string()];
        let r = HtmlReport {
            id: 7,
            name: "scan <1>",
            state: "failed",
            errors: &errors,
            store_id: "abc123",
            timings: vec![("wall time".into(), "0:01:02".into())],
            table: "axis method\nX    CS bp",
            iso: &[],
            files: &files,
            rig: vec![(
                "axis x".into(),
                "(c)2015 Physik Instrumente(PI) C-863".into(),
            )],
            campaign_text: "[campaign]\nname = \"a<b\"\n",
            campaign_origin: "/tmp/c.toml",
        };
        let h = report_html(&r);
        assert!(h.starts_with("<!DOCTYPE html>"));
        assert!(h.contains("csmetro campaign 7 — scan &lt;1&gt;"));
        assert!(h.contains("error: a &lt;b&gt; &amp; c"));
        assert!(
            h.contains("name = &quot;a&lt;b&quot;"),
            "campaign file escaped"
        );
        assert!(h.contains("Physik Instrumente(PI) C-863"));
        assert!(h.contains("0:01:02") && h.contains("abc123"));
        // The PNG is embedded; nothing is loaded from elsewhere.
        let uri = png_uri(&png);
        assert!(h.contains(&format!("src=\"{uri}\"")));
        assert!(!h.contains("src=\"http") && !h.contains("<script"));
        assert!(h.contains("@media print"));
    }
}
