//! Bad input never panics: every case is a clear error naming the input, or a reject with a reason.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use lfi_bridge::imageio;
use lfi_bridge::sim::{SimConfig, Simulator};
use opencv::core::{self, Mat, Vector};
use opencv::prelude::*;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_lfi-bridge"))
}

fn run(args: &[&str]) -> Output {
    let out = bin().args(args).output().expect("binary runs");
    // A panic exits with 101; every handled failure uses 1 or 2.
    assert_ne!(out.status.code(), Some(101), "panicked: {}", String::from_utf8_lossy(&out.stderr));
    out
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// A knowledge base enrolled from the small simulator's templates, and one of its scenes.
fn setup(dir: &Path) -> (PathBuf, PathBuf) {
    let sim = Simulator::new(SimConfig { width: 800, height: 600, seed: 3, noise: None }).unwrap();
    let kb = dir.join("kb.toml");
    for (i, (name, face, img)) in sim.templates().unwrap().into_iter().enumerate() {
        let p = dir.join(format!("{name}_{face}.png"));
        imageio::write_png(&p, &img).unwrap();
        let id = (i / 2 + 1).to_string();
        let out =
            run(&["enroll", "--kb", kb.to_str().unwrap(), "--type", &name, "--id", &id, "--face", face.as_str(), p.to_str().unwrap()]);
        assert!(out.status.success(), "{}", text(&out.stderr));
    }
    let scene = sim.scene_with(0, "clean").unwrap();
    let p = dir.join("scene.png");
    imageio::write_png(&p, &scene.image).unwrap();
    (kb, p)
}

#[test]
fn unreadable_images_are_named_errors_and_json_gets_a_frame_error_line() {
    let dir = tempfile::tempdir().unwrap();
    let (kb, good) = setup(dir.path());
    let missing = dir.path().join("missing.png");
    let empty = dir.path().join("empty.png");
    std::fs::write(&empty, b"").unwrap();
    let truncated = dir.path().join("truncated.png");
    let bytes = std::fs::read(&good).unwrap();
    std::fs::write(&truncated, &bytes[..bytes.len() / 3]).unwrap();
    let not_image = dir.path().join("notes.png");
    std::fs::write(&not_image, b"this is a text file").unwrap();
    for bad in [&missing, &empty, &truncated, &not_image] {
        let out = run(&["estimate", "--kb", kb.to_str().unwrap(), "--json", bad.to_str().unwrap()]);
        assert_eq!(out.status.code(), Some(1), "{}", text(&out.stderr));
        let name = bad.file_name().unwrap().to_str().unwrap();
        assert!(text(&out.stderr).contains(name), "stderr names the file: {}", text(&out.stderr));
        let line: serde_json::Value = serde_json::from_str(text(&out.stdout).trim()).unwrap();
        assert_eq!(line["parts"][0]["reason"], "frame error");
        assert_eq!(line["parts"][0]["accepted"], false);
    }
    // The good image in the same call is still estimated.
    let out = run(&["estimate", "--kb", kb.to_str().unwrap(), "--json", missing.to_str().unwrap(), good.to_str().unwrap()]);
    let lines: Vec<&str> = std::str::from_utf8(&out.stdout).unwrap().lines().collect();
    assert_eq!(lines.len(), 2);
    let second: serde_json::Value = serde_json::from_str(lines[1]).unwrap();
    assert_eq!(second["parts"][0]["accepted"], true, "{}", lines[1]);
}

#[test]
fn tiny_colour_and_sixteen_bit_images() {
    let dir = tempfile::tempdir().unwrap();
    let (kb, good) = setup(dir.path());
    let kb = kb.to_str().unwrap();
    let one = dir.path().join("one.png");
    let m = Mat::new_rows_cols_with_default(1, 1, core::CV_8UC1, core::Scalar::all(7.0)).unwrap();
    opencv::imgcodecs::imwrite(one.to_str().unwrap(), &m, &Vector::new()).unwrap();
    let out = run(&["estimate", "--kb", kb, one.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out.stderr).contains("1 x 1"), "{}", text(&out.stderr));

    // Colour and 16-bit frames of the same scene are converted and estimated like the gray one.
    let gray = opencv::imgcodecs::imread(good.to_str().unwrap(), opencv::imgcodecs::IMREAD_GRAYSCALE).unwrap();
    let mut colour = Mat::default();
    opencv::imgproc::cvt_color(&gray, &mut colour, opencv::imgproc::COLOR_GRAY2BGR, 0).unwrap();
    let cpath = dir.path().join("colour.png");
    opencv::imgcodecs::imwrite(cpath.to_str().unwrap(), &colour, &Vector::new()).unwrap();
    let mut deep = Mat::default();
    gray.convert_to(&mut deep, core::CV_16U, 257.0, 0.0).unwrap();
    let dpath = dir.path().join("deep.png");
    opencv::imgcodecs::imwrite(dpath.to_str().unwrap(), &deep, &Vector::new()).unwrap();
    for p in [&cpath, &dpath] {
        let out = run(&["estimate", "--kb", kb, "--json", p.to_str().unwrap()]);
        assert!(out.status.success(), "{}", text(&out.stderr));
        let v: serde_json::Value = serde_json::from_str(text(&out.stdout).trim()).unwrap();
        assert_eq!(v["parts"][0]["accepted"], true, "{}", text(&out.stdout));
    }
}

#[test]
fn missing_or_corrupt_knowledge_bases_are_named_errors() {
    let dir = tempfile::tempdir().unwrap();
    let (kb, good) = setup(dir.path());
    let good = good.to_str().unwrap();
    let missing = dir.path().join("nope.toml");
    let out = run(&["estimate", "--kb", missing.to_str().unwrap(), good]);
    assert_eq!(out.status.code(), Some(2));
    assert!(text(&out.stderr).contains("nope.toml"), "{}", text(&out.stderr));
    let text_kb = std::fs::read_to_string(&kb).unwrap();
    // Every outline coordinate of the second template scaled: far outside its image.
    let scaled = |by: f64| {
        let mut v: toml::Table = text_kb.parse().unwrap();
        let outline = v["template"].as_array_mut().unwrap()[1].as_table_mut().unwrap()["outline"].as_array_mut().unwrap();
        for p in outline.iter_mut().flat_map(|p| p.as_array_mut().unwrap().iter_mut()) {
            *p = toml::Value::Float(p.as_float().unwrap() * by);
        }
        toml::to_string(&v).unwrap()
    };
    let last_record = text_kb.rfind("[[template]]").unwrap();
    for (name, body) in [
        ("half.toml", text_kb[..text_kb.len() / 2].to_string()),
        ("cut_at_a_record.toml", text_kb[..last_record].to_string()),
        ("outline_1e300.toml", scaled(1e300)),
        ("outline_1000.toml", scaled(1000.0)),
        ("other.toml", "format = \"spreadsheet\"\nversion = 1\n".to_string()),
        ("future.toml", text_kb.replace("version = 1", "version = 7")),
        ("empty.toml", String::new()),
    ] {
        let p = dir.path().join(name);
        std::fs::write(&p, body).unwrap();
        let out = run(&["estimate", "--kb", p.to_str().unwrap(), good]);
        assert_eq!(out.status.code(), Some(2), "{name}: {}", text(&out.stderr));
        assert!(text(&out.stderr).contains(name), "{name}: {}", text(&out.stderr));
        if name.starts_with("outline") {
            assert!(text(&out.stderr).contains("template 2 ("), "{name} names the template: {}", text(&out.stderr));
        }
    }
}

#[test]
fn enrolling_an_image_without_a_part_fails_and_leaves_the_knowledge_base_alone() {
    let dir = tempfile::tempdir().unwrap();
    let (kb, _) = setup(dir.path());
    let before = std::fs::read(&kb).unwrap();
    let blank = dir.path().join("blank.png");
    imageio::write_png(&blank, &lfi_bridge::vision::GrayImage::new(400, 300, 60)).unwrap();
    let out = run(&["enroll", "--kb", kb.to_str().unwrap(), "--type", "x", "--id", "9", "--face", "up", blank.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2));
    assert!(text(&out.stderr).contains("blank.png") && text(&out.stderr).contains("no part"), "{}", text(&out.stderr));
    assert_eq!(std::fs::read(&kb).unwrap(), before);
    let out = run(&["enroll", "--kb", kb.to_str().unwrap(), "--type", "x", "--id", "1", "--face", "up", blank.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2));
    let out = run(&["enroll", "--kb", kb.to_str().unwrap(), "--type", "x", "--id", "70000", "--face", "up", blank.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2), "an id beyond 16 bits is a usage error");
    let out = run(&["enroll", "--kb", kb.to_str().unwrap(), "--type", "x", "--id", "3", "--face", "sideways", blank.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2));
}

#[test]
fn a_frame_with_no_part_is_an_empty_estimate() {
    let dir = tempfile::tempdir().unwrap();
    let (kb, _) = setup(dir.path());
    let sim = Simulator::new(SimConfig { width: 800, height: 600, seed: 3, noise: None }).unwrap();
    let p = dir.path().join("belt.png");
    imageio::write_png(&p, &sim.scene_with(0, "empty").unwrap().image).unwrap();
    let out = run(&["estimate", "--kb", kb.to_str().unwrap(), "--json", p.to_str().unwrap()]);
    assert!(out.status.success());
    let v: serde_json::Value = serde_json::from_str(text(&out.stdout).trim()).unwrap();
    assert_eq!(v["parts"].as_array().unwrap().len(), 0);
}
