//! `report.html`: one self-contained page per run (pictures embedded), to read a run at a
//! glance: the map with the paths, the self-check, the reader's account, the accuracy when
//! there is ground truth, timings, and the configuration keys that differ from the defaults.

use pfslam::config::Config;
use std::fmt::Write as _;
use std::path::Path;

/// Writes `summary.json` and the `report.html` made from it into `out`, with the map
/// pictures `out` holds (`map_caption` for `map.png`).
pub fn write_summary_and_report(
    out: &Path,
    summary: &serde_json::Value,
    config: &Config,
    map_caption: &str,
) -> anyhow::Result<()> {
    let text = serde_json::to_string_pretty(summary)?;
    pfslam_io::write_bytes_atomic(&out.join("summary.json"), text.as_bytes())?;
    let images = [(map_caption, "map.png"), ("binary map", "binary_map.png")];
    write_report(out, summary, config, &images)
}

/// Writes `report.html` into `out` from the run's `summary` and the PNGs named in `images`
/// (file names in `out`; missing ones are left out).
fn write_report(
    out: &Path,
    summary: &serde_json::Value,
    config: &Config,
    images: &[(&str, &str)],
) -> anyhow::Result<()> {
    let mut html = String::with_capacity(1 << 20);
    let title = summary["recording"].as_str().unwrap_or("pfslam run");
    let _ = writeln!(
        html,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <title>pfslam: {t}</title><style>{STYLE}</style></head><body>\n<h1>pfslam: {t}</h1>",
        t = escape(title)
    );
    quality_section(&mut html, &summary["quality"]);
    for (caption, file) in images {
        let Ok(bytes) = std::fs::read(out.join(file)) else {
            continue;
        };
        let _ = writeln!(
            html,
            "<figure><img alt=\"{c}\" src=\"data:image/png;base64,{b}\">\
             <figcaption>{c}</figcaption></figure>",
            c = escape(caption),
            b = pfslam_viz::base64(&bytes)
        );
    }
    for (heading, key) in [
        ("Accuracy against the ground truth", "slam_vs_ground_truth"),
        (
            "The filter before the back end, against the ground truth",
            "front_end_vs_ground_truth",
        ),
        (
            "Dead reckoning against the ground truth",
            "dead_reckoning_vs_ground_truth",
        ),
        ("Input: what was read, dropped and repaired", "input"),
        ("Filter", "stats"),
        ("Back end", "graph"),
        ("Timings (s)", "timings_s"),
    ] {
        if let Some(v) = summary.get(key).filter(|v| !v.is_null()) {
            let _ = writeln!(html, "<h2>{}</h2>", escape(heading));
            table(&mut html, v);
        }
    }
    config_section(&mut html, config);
    html.push_str("</body></html>\n");
    pfslam_io::write_bytes_atomic(&out.join("report.html"), html.as_bytes())?;
    Ok(())
}

const STYLE: &str = "body{font-family:sans-serif;max-width:70em;margin:auto;padding:1em}\
table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #ccc;padding:2px 8px;\
text-align:left;vertical-align:top}img{max-width:100%}.ok{color:#070}.suspect{color:#b00}\
figure{display:inline-block;margin:0.5em;max-width:48%}";

fn quality_section(html: &mut String, quality: &serde_json::Value) {
    let status = quality["status"].as_str().unwrap_or("unknown");
    let _ = writeln!(
        html,
        "<h2>Self-check: <span class=\"{s}\">{s}</span></h2>",
        s = escape(status)
    );
    if let Some(reasons) = quality["reasons"].as_array().filter(|r| !r.is_empty()) {
        html.push_str("<ul>");
        for r in reasons {
            let _ = write!(html, "<li>{}</li>", escape(r.as_str().unwrap_or("")));
        }
        html.push_str("</ul>\n");
    }
    if let Some(signals) = quality.get("signals") {
        table(html, signals);
    }
}

/// The configuration keys whose values differ from the defaults.
fn config_section(html: &mut String, config: &Config) {
    let (mut ours, mut defaults) = (Vec::new(), Vec::new());
    if let (Ok(a), Ok(b)) = (
        serde_json::to_value(config),
        serde_json::to_value(Config::default()),
    ) {
        flatten("", &a, &mut ours);
        flatten("", &b, &mut defaults);
    }
    let changed: Vec<&(String, String)> = ours
        .iter()
        .filter(|(k, v)| !defaults.iter().any(|(dk, dv)| dk == k && dv == v))
        .collect();
    html.push_str("<h2>Configuration</h2>\n");
    if changed.is_empty() {
        html.push_str("<p>The defaults (<code>pfslam print-config</code>).</p>\n");
        return;
    }
    html.push_str("<p>Keys that differ from the defaults:</p><table>");
    for (k, v) in changed {
        let _ = write!(
            html,
            "<tr><td><code>{}</code></td><td>{}</td></tr>",
            escape(k),
            escape(v)
        );
    }
    html.push_str("</table>\n");
}

/// `[(dotted.key, value)]` of the leaves of `v`.
fn flatten(prefix: &str, v: &serde_json::Value, out: &mut Vec<(String, String)>) {
    match v {
        serde_json::Value::Object(map) => {
            for (k, x) in map {
                let key = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                flatten(&key, x, out);
            }
        }
        other => out.push((prefix.to_string(), other.to_string())),
    }
}

/// A JSON object as a two-column table (nested objects as nested tables).
fn table(html: &mut String, v: &serde_json::Value) {
    match v {
        serde_json::Value::Object(map) => {
            html.push_str("<table>");
            for (k, x) in map {
                let _ = write!(html, "<tr><th>{}</th><td>", escape(k));
                table(html, x);
                html.push_str("</td></tr>");
            }
            html.push_str("</table>\n");
        }
        serde_json::Value::Number(n) => match n.as_f64() {
            Some(f) if n.is_f64() => {
                let _ = write!(html, "{}", format_number(f));
            }
            _ => {
                let _ = write!(html, "{n}");
            }
        },
        serde_json::Value::String(s) => html.push_str(&escape(s)),
        other => html.push_str(&escape(&other.to_string())),
    }
}

/// Four significant digits, without exponent for everyday magnitudes.
fn format_number(f: f64) -> String {
    if f == 0.0 || (1e-3..1e6).contains(&f.abs()) {
        let digits = (3 - f.abs().log10().floor() as i32).clamp(0, 6) as usize;
        format!("{f:.digits$}")
    } else {
        format!("{f:.3e}")
    }
}

fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            _ => out.push(c),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn text_is_escaped_and_numbers_rounded() {
        assert_eq!(escape("<a & \"b\">"), "&lt;a &amp; &quot;b&quot;&gt;");
        assert_eq!(format_number(0.021734), "0.02173");
        assert_eq!(format_number(1234.5678), "1235");
        assert_eq!(format_number(2.5e-7), "2.500e-7");
    }

    #[test]
    fn only_changed_keys_are_listed() {
        let mut config = Config::default();
        config.filter.particles = 7;
        let mut html = String::new();
        config_section(&mut html, &config);
        assert!(html.contains("filter.particles"), "{html}");
        assert_eq!(html.matches("<tr>").count(), 1, "{html}");
        let mut html = String::new();
        config_section(&mut html, &Config::default());
        assert!(html.contains("The defaults"), "{html}");
    }
}
