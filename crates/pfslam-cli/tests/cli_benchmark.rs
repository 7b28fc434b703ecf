//! `pfslam benchmark` end to end.

use super::pfslam;

#[test]
fn benchmark_scores_mit_csail_against_its_relations() {
    let Some(data) = super::data_dir("benchmark_scores_mit_csail_against_its_relations") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let o = pfslam()
        .args(["benchmark", "--only", "mit-csail", "--data"])
        .arg(&data)
        .arg("--out")
        .arg(dir.path())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let row = stdout
        .lines()
        .find(|l| l.starts_with("| mit-csail |"))
        .unwrap_or_else(|| panic!("no row: {stdout}"));
    // every relation of the file is scored: the trajectory has a pose at every scan
    assert!(row.contains("| 1172/1172 |"), "{row}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("benchmark.json")).unwrap())
            .unwrap();
    let t = json[0]["trans_mean_m"].as_f64().unwrap();
    assert!(t.is_finite() && t > 0.0, "{json}");
    assert!(dir.path().join("mit-csail.tum").is_file());
}

#[test]
fn benchmark_without_recordings_exits_2() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir(dir.path().join("freiburg")).unwrap();
    let o = pfslam()
        .args(["benchmark", "--data"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("no recording with relations"));
}
