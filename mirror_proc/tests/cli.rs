//! The offline command line, run as a user would.

use std::path::Path;
use std::process::{Command, Output};

fn mirror_proc(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mirror_proc"))
        .args(args)
        .output()
        .unwrap()
}

fn ok(args: &[&str]) -> String {
    let out = mirror_proc(args);
    assert!(
        out.status.success(),
        "{args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// Runs a command expected to fail; returns its single line of stderr.
fn fails(args: &[&str]) -> String {
    let out = mirror_proc(args);
    assert!(!out.status.success(), "{args:?} should fail");
    let err = String::from_utf8(out.stderr).unwrap();
    assert_eq!(
        err.trim_end().lines().count(),
        1,
        "error is not one line: {err}"
    );
    err.trim_end().to_string()
}

fn json(text: &str) -> serde_json::Value {
    serde_json::from_str(text).unwrap()
}

fn p(dir: &Path, name: &str) -> String {
    dir.join(name).display().to_string()
}

#[test]
fn noiseless_simulation_calibrates_exactly_with_every_method() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    ok(&[
        "simulate",
        "--mirror",
        "2",
        "--noise",
        "none",
        "--train",
        "12",
        "--test",
        "20",
        "--direct",
        "10",
        "--out",
        d.to_str().unwrap(),
    ]);
    for method in ["paper", "joint", "joint+kinematics"] {
        let cal = p(d, &format!("{method}.json"));
        ok(&[
            "calibrate",
            "--rig",
            &p(d, "rig.toml"),
            "--samples",
            &p(d, "train.csv"),
            "--method",
            method,
            "--out",
            &cal,
        ]);
        let e = json(&ok(&[
            "evaluate",
            "--rig",
            &p(d, "rig.toml"),
            "--calibration",
            &cal,
            "--samples",
            &p(d, "test.csv"),
        ]));
        assert!(e["mirror_3d_mm"].as_f64().unwrap() < 1e-6, "{method}: {e}");
        assert!(e["mirror_2d_px"].as_f64().unwrap() < 1e-6, "{method}: {e}");
        assert!(e["direct_3d_mm"].as_f64().unwrap() < 1e-6, "{method}: {e}");
        assert_eq!(e["mirror_count"], 20);
        assert_eq!(e["direct_count"], 10);
    }
}

#[test]
fn noisy_simulation_approaches_the_truth_files_figures() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    ok(&["simulate", "--mirror", "0", "--out", d.to_str().unwrap()]);
    let eval = |cal: &str| {
        json(&ok(&[
            "evaluate",
            "--rig",
            &p(d, "rig.toml"),
            "--calibration",
            cal,
            "--samples",
            &p(d, "test.csv"),
        ]))
    };
    // truth.json holds the true mirror cameras and encoder offsets: the noise floor.
    let floor = eval(&p(d, "truth.json"));
    let cal = p(d, "cal.json");
    ok(&[
        "calibrate",
        "--rig",
        &p(d, "rig.toml"),
        "--samples",
        &p(d, "train.csv"),
        "--out",
        &cal,
    ]);
    assert_eq!(
        json(&std::fs::read_to_string(&cal).unwrap())["method"],
        "joint+kinematics",
        "the default method"
    );
    let ours = eval(&cal);
    for key in ["mirror_2d_px", "mirror_3d_mm"] {
        let (a, b) = (ours[key].as_f64().unwrap(), floor[key].as_f64().unwrap());
        assert!(a < 1.15 * b, "{key}: {a} vs floor {b}");
    }
    // The estimated encoder offsets also help direct views, against the nominal arm model.
    let mut nominal = json(&std::fs::read_to_string(d.join("truth.json")).unwrap());
    nominal.as_object_mut().unwrap().remove("joint_offsets");
    std::fs::write(d.join("nominal.json"), nominal.to_string()).unwrap();
    let nominal = eval(&p(d, "nominal.json"));
    let (a, b) = (
        ours["direct_2d_px"].as_f64().unwrap(),
        nominal["direct_2d_px"].as_f64().unwrap(),
    );
    assert!(a < 0.8 * b, "direct 2D {a} px vs nominal model {b} px");
}

#[test]
fn bad_input_gives_one_line_naming_the_file_and_place() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    ok(&[
        "simulate",
        "--train",
        "8",
        "--test",
        "4",
        "--direct",
        "0",
        "--out",
        d.to_str().unwrap(),
    ]);
    let rig = p(d, "rig.toml");
    let train = std::fs::read_to_string(d.join("train.csv")).unwrap();
    let write = |name: &str, text: &str| {
        std::fs::write(d.join(name), text).unwrap();
        p(d, name)
    };
    let calibrate = |samples: &str| fails(&["calibrate", "--rig", &rig, "--samples", samples]);

    let missing = write("missing.csv", &train.replace("right_v", "rightv"));
    assert!(calibrate(&missing).ends_with("missing.csv: line 1: missing column `right_v`"));

    let mut lines: Vec<String> = train.lines().map(String::from).collect();
    lines[3] = lines[3]
        .rsplit_once(',')
        .map(|(head, _)| format!("{head},NaN"))
        .unwrap();
    let nan = write("nan.csv", &(lines.join("\n") + "\n"));
    assert!(calibrate(&nan).ends_with("nan.csv: line 4: column `right_v`: `NaN` is not finite"));

    let three_joints = write("q3.csv", &train.replace(",q3,", ",x3,"));
    let e = calibrate(&three_joints);
    assert!(
        e.contains("q3.csv: line 1: 3 joint columns (q0..q2) but the rig's arm has 4 joints"),
        "{e}"
    );

    let e = fails(&[
        "calibrate",
        "--rig",
        &rig,
        "--samples",
        &p(d, "train.csv"),
        "--method",
        "best",
    ]);
    assert!(e.contains("--method: unknown method `best`"), "{e}");

    let bad_rig = write(
        "bad.toml",
        &std::fs::read_to_string(&rig)
            .unwrap()
            .replacen("fx = ", "fx = \"wide\" #", 1),
    );
    let e = fails(&[
        "calibrate",
        "--rig",
        &bad_rig,
        "--samples",
        &p(d, "train.csv"),
    ]);
    assert!(e.contains("bad.toml: line "), "{e}");

    let bad_cal = write("bad.json", "{\"method\": \"joint\", \"cameras\": []}");
    let e = fails(&[
        "evaluate",
        "--rig",
        &rig,
        "--calibration",
        &bad_cal,
        "--samples",
        &p(d, "test.csv"),
    ]);
    assert!(
        e.contains("bad.json: line 1: missing field `train_rms_px`"),
        "{e}"
    );

    let e = fails(&[
        "calibrate",
        "--rig",
        &p(d, "absent.toml"),
        "--samples",
        &p(d, "train.csv"),
    ]);
    assert!(e.contains("absent.toml: cannot read"), "{e}");

    let two = write(
        "two.csv",
        &(train.lines().take(3).collect::<Vec<_>>().join("\n") + "\n"),
    );
    let e = calibrate(&two);
    assert!(
        e.contains("two.csv: 2 usable mirror samples; at least 3 are needed"),
        "{e}"
    );
}

#[test]
fn quick_experiment_prints_the_table_and_writes_figures() {
    let dir = tempfile::tempdir().unwrap();
    let (j, plot) = (p(dir.path(), "e.json"), p(dir.path(), "curve.svg"));
    let out = ok(&["experiment", "--quick", "--json", &j, "--plot", &plot]);
    for needle in [
        "31.55",
        "5.12",
        "18.47",
        "5.66",
        "joint+kinematics (ours)",
        "oracle",
        "noise floor",
    ] {
        assert!(out.contains(needle), "table lacks {needle}:\n{out}");
    }
    let result = json(&std::fs::read_to_string(&j).unwrap());
    assert_eq!(result["mirrors"].as_array().unwrap().len(), 3);
    assert_eq!(result["sizes"], serde_json::json!([3, 5, 10, 20]));
    let svg = std::fs::read_to_string(&plot).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("joint+kinematics, mirror"));
}

/// `export` of a calibration made through a URDF rig (with calibration
/// files) and through the DH rig: the corrected arm gives at `q` what the
/// calibrated model gives at `q + joint_offsets`, and the transforms hold
/// the calibration's mirror cameras.
#[test]
fn export_writes_a_corrected_arm_and_the_mirror_transforms() {
    let urdf_rig =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/data/rigs/nico_urdf/rig.toml");
    for rig_arg in [Some(urdf_rig.to_str().unwrap()), None] {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let mut sim = vec![
            "simulate",
            "--train",
            "20",
            "--test",
            "4",
            "--direct",
            "0",
            "--out",
            d.to_str().unwrap(),
        ];
        if let Some(r) = rig_arg {
            sim.extend(["--rig", r]);
        }
        ok(&sim);
        let (rig, cal, out) = (p(d, "rig.toml"), p(d, "cal.json"), p(d, "export"));
        ok(&[
            "calibrate",
            "--rig",
            &rig,
            "--samples",
            &p(d, "train.csv"),
            "--out",
            &cal,
        ]);
        let listed = ok(&[
            "export",
            "--rig",
            &rig,
            "--calibration",
            &cal,
            "--out",
            &out,
        ]);
        let calibration = formats::calibration::read(&cal).unwrap();
        let original = formats::rig::read(&rig).unwrap();
        let arm = original.arm.as_ref().unwrap();
        assert_eq!(calibration.joint_names.as_ref(), Some(&arm.joint_names()));
        let offsets = calibration.joint_offsets.clone().unwrap();
        assert!(offsets.iter().any(|o| o.abs() > 1e-4), "{offsets:?}");
        let corrected = formats::rig::read(d.join("export/rig.corrected.toml")).unwrap();
        let fixed_arm = corrected.arm.as_ref().unwrap();
        assert_eq!(fixed_arm.joint_names(), arm.joint_names());
        for i in 0..10 {
            let q: Vec<f64> = arm
                .limits()
                .iter()
                .enumerate()
                .map(|(j, (lo, hi))| lo + (hi - lo) * (0.5 + 0.4 * ((3 * i + j) as f64).cos()))
                .collect();
            let want = arm.end_effector(&q, &offsets).unwrap();
            let got = fixed_arm.end_effector(&q, &[]).unwrap();
            assert!((want - got).norm() < 1e-9, "{want} vs {got}");
        }
        assert_eq!(
            listed.contains(".corrected.urdf"),
            rig_arg.is_some(),
            "{listed}"
        );
        // The Foxglove snapshot: each mirror camera's frame is its pose.
        let tf = json(&std::fs::read_to_string(d.join("export/frame_transforms.json")).unwrap());
        for (k, cam) in calibration.mirror_cameras(&original).iter().enumerate() {
            let t = tf["transforms"]
                .as_array()
                .unwrap()
                .iter()
                .find(|t| t["child_frame_id"] == ["mirror_camera_left", "mirror_camera_right"][k])
                .unwrap();
            assert_eq!(t["parent_frame_id"], "world");
            let v = |o: &serde_json::Value, key: &str| o[key].as_f64().unwrap();
            let centre = nalgebra::Vector3::new(
                v(&t["translation"], "x"),
                v(&t["translation"], "y"),
                v(&t["translation"], "z"),
            ) * 1000.0;
            assert!((centre - cam.center).norm() < 1e-9);
            let r = &t["rotation"];
            let q = nalgebra::UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(
                v(r, "w"),
                v(r, "x"),
                v(r, "y"),
                v(r, "z"),
            ));
            let world_from_camera = q.to_rotation_matrix().into_inner();
            assert!((world_from_camera.transpose() - cam.camera_from_world).norm() < 1e-9);
        }
        let mirror = json(&std::fs::read_to_string(d.join("export/mirror.json")).unwrap());
        let normal = calibration.plane.as_ref().unwrap().normal;
        for i in 0..3 {
            assert!((mirror["plane"]["normal"][i].as_f64().unwrap() - normal[i]).abs() < 1e-12);
        }
    }
}

#[test]
fn calibrate_across_placements_estimates_the_tool_and_refuses_what_it_cannot() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for m in 0..3 {
        let out = p(d, &format!("m{m}"));
        let m = m.to_string();
        ok(&[
            "simulate", "--mirror", &m, "--noise", "none", "--train", "12", "--test", "5",
            "--direct", "5", "--out", &out,
        ]);
    }
    // The rig as a user measured it: the tool 5 mm off.
    let rig_text = std::fs::read_to_string(d.join("m0/rig.toml")).unwrap();
    let tool_line = rig_text
        .lines()
        .find(|l| l.starts_with("tool = "))
        .expect("the rig states its tool");
    let true_tool: Vec<f64> = tool_line["tool = ".len()..]
        .trim_matches(|c| c == '[' || c == ']')
        .split(',')
        .map(|v| v.trim().parse().unwrap())
        .collect();
    let wrong = format!(
        "tool = [{}, {}, {}]",
        true_tool[0] + 3.0,
        true_tool[1] - 4.0,
        true_tool[2]
    );
    std::fs::write(d.join("wrong.toml"), rig_text.replace(tool_line, &wrong)).unwrap();
    let rig = p(d, "wrong.toml");
    let samples: Vec<String> = (0..3).map(|m| p(d, &format!("m{m}/train.csv"))).collect();

    // One placement's mirror views cannot place the base.
    let err = fails(&[
        "calibrate",
        "--rig",
        &rig,
        "--samples",
        &samples[0],
        "--estimate",
        "base",
    ]);
    assert!(err.contains("cannot estimate the arm's base"), "{err}");
    let err = fails(&[
        "calibrate",
        "--rig",
        &rig,
        "--samples",
        &samples[0],
        "--estimate",
        "hand",
    ]);
    assert!(err.contains("--estimate") && err.contains("hand"), "{err}");

    let cal_path = p(d, "cal.json");
    ok(&[
        "calibrate",
        "--rig",
        &rig,
        "--samples",
        &samples[0],
        "--samples",
        &samples[1],
        "--samples",
        &samples[2],
        "--method",
        "joint",
        "--estimate",
        "tool",
        "--out",
        &cal_path,
    ]);
    let cal = json(&std::fs::read_to_string(&cal_path).unwrap());
    assert_eq!(cal["placements"].as_array().unwrap().len(), 3, "{cal}");
    assert!(
        cal.get("world_from_base").is_none(),
        "the base was not asked for"
    );
    let tool: Vec<f64> = cal["tool"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    for k in 0..3 {
        assert!(
            (tool[k] - true_tool[k]).abs() < 0.01,
            "tool {tool:?}, truth {true_tool:?}"
        );
    }
    // Each placement's cameras, with the corrected tool: noiseless, so exact.
    for m in 0..3 {
        let e = json(&ok(&[
            "evaluate",
            "--rig",
            &rig,
            "--calibration",
            &cal_path,
            "--samples",
            &p(d, &format!("m{m}/test.csv")),
            "--placement",
            &m.to_string(),
        ]));
        let mm = e["mirror_3d_mm"].as_f64().unwrap();
        assert!(mm < 0.01, "placement {m}: {e}");
    }
    let err = fails(&[
        "evaluate",
        "--rig",
        &rig,
        "--calibration",
        &cal_path,
        "--samples",
        &samples[0],
        "--placement",
        "3",
    ]);
    assert!(
        err.contains("--placement") && err.contains("3 placement"),
        "{err}"
    );
    // The export's rig carries the tool as calibrated.
    ok(&[
        "export",
        "--rig",
        &rig,
        "--calibration",
        &cal_path,
        "--out",
        &p(d, "export"),
    ]);
    let corrected = formats::rig::read(d.join("export/rig.corrected.toml")).unwrap();
    let exported = corrected.arm.unwrap().tool;
    assert!((exported - nalgebra::Vector3::from_vec(tool)).norm() < 1e-9);
}
