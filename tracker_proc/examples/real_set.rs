//! Each lever of the detector measured on the real-image set: recall (of the
//! truth and of OpenCV 5's finds), centre error against the line-fit truth,
//! false markers, and time per image as a ratio to OpenCV 4.6's stock pass
//! timed in the same run.
//!
//! ```text
//! bash scripts/setup.sh   # target/pyenv; then: target/pyenv/bin/pip install opencv-contrib-python-headless==5.*
//! cargo run --release -p tracker_proc --example real_set
//! ```

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use opencv::core::Mat;
use opencv::imgcodecs;
use tracker_proc::real_set::{Found, RealSet, Report, readings_near, stock_pass, table};
use tracker_proc::{Checks, Correction, Detector, Options, Refine, StockPass, ThresholdWindows};

fn main() -> Result<()> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let out = root.join("target/real_markers");
    let status = Command::new(root.join("target/pyenv/bin/python"))
        .arg(root.join("scripts/real_markers.py"))
        .arg(root.join("tests/data/real_markers"))
        .arg(&out)
        .status()
        .context("running scripts/real_markers.py with target/pyenv/bin/python")?;
    if !status.success() {
        bail!("scripts/real_markers.py failed");
    }
    let set = RealSet::load(&out)?;
    let images: Vec<Mat> = set
        .variants
        .iter()
        .map(|v| {
            let path = set.dir.join(&v.file);
            imgcodecs::imread(&path, imgcodecs::IMREAD_GRAYSCALE)
                .with_context(|| format!("reading {}", path.display()))
        })
        .collect::<Result<_>>()?;

    let ours = Options::new(true);
    let none = Options {
        keep_close_candidates: false,
        reread_refined: false,
        opencv_reading: false,
        refine: Refine::Subpix,
        own_search: false,
        ..ours
    };
    // Levers added one at a time, then each of ours swapped for an alternative.
    let levers: Vec<(&str, Options)> = vec![
        ("OpenCV candidates, our reading, cornerSubPix", none),
        (
            "+ keep close candidates",
            Options {
                keep_close_candidates: true,
                ..none
            },
        ),
        (
            "+ re-read near misses on edge-fitted corners",
            Options {
                keep_close_candidates: true,
                reread_refined: true,
                ..none
            },
        ),
        (
            "+ edge-line corners",
            Options {
                opencv_reading: false,
                own_search: false,
                ..ours
            },
        ),
        (
            "+ near misses read as OpenCV reads",
            Options {
                own_search: false,
                ..ours
            },
        ),
        ("+ our candidate search, the same candidates (ours)", ours),
        (
            "  ours, polygon corners",
            Options {
                refine: Refine::None,
                ..ours
            },
        ),
        (
            "  ours, correcting bits (own codes)",
            Options {
                correction: Correction::OwnCodes { max: 2 },
                ..ours
            },
        ),
        (
            "  ours, correcting bits (sparing foreign codes)",
            Options {
                correction: Correction::SparingForeign { max: 2 },
                ..ours
            },
        ),
        (
            "  ours, 1 white border cell at half contrast",
            Options {
                checks: Checks {
                    border_level: 0.5,
                    ..ours.checks
                },
                ..ours
            },
        ),
        (
            "  ours, no margin check",
            Options {
                checks: Checks {
                    min_margin: 0.0,
                    ..ours.checks
                },
                ..ours
            },
        ),
        (
            "  ours, no pattern check (misfit)",
            Options {
                checks: Checks {
                    max_misfit: f64::INFINITY,
                    ..ours.checks
                },
                ..ours
            },
        ),
        (
            "  ours, threshold windows 3 and 23 px",
            Options {
                threshold_windows: ThresholdWindows {
                    min: 3,
                    max: 23,
                    step: 20,
                },
                ..ours
            },
        ),
        (
            "  ours, threshold windows 3 and 13 px",
            Options {
                threshold_windows: ThresholdWindows {
                    min: 3,
                    max: 13,
                    step: 10,
                },
                ..ours
            },
        ),
        (
            "  ours, threshold windows 7 and 17 px",
            Options {
                threshold_windows: ThresholdWindows {
                    min: 7,
                    max: 17,
                    step: 10,
                },
                ..ours
            },
        ),
        (
            "  ours, threshold window 13 px",
            Options {
                threshold_windows: ThresholdWindows::single(13),
                ..ours
            },
        ),
        (
            "  ours, threshold window 7 px",
            Options {
                threshold_windows: ThresholdWindows::single(7),
                ..ours
            },
        ),
    ];
    // The row whose misses and false reports are explained below.
    let ours_row = levers
        .iter()
        .position(|(name, _)| name.ends_with("(ours)"))
        .context("no lever is marked (ours)")?;

    let stock5: Report = {
        let mut r = Report::default();
        for v in &set.variants {
            r.add(v, &v.stock.iter().map(Found::from).collect::<Vec<_>>());
        }
        r
    };
    println!(
        "{} images from {} photographs; OpenCV {} column from the set\n",
        set.variants.len(),
        set.variants
            .iter()
            .filter(|v| v.variant == "original")
            .count(),
        set.opencv
    );
    println!(
        "{:<58} {:>9} {:>11} {:>7} {:>6} {:>5} {:>12}",
        "detector", "found", "of OpenCV 5", "median", "max", "false", "time / stock"
    );
    let line = |name: &str, r: &Report, ratio: Option<f64>| {
        let (median, max) = r.all.center_error();
        println!(
            "{:<58} {:>4}/{:<4} {:>5}/{:<5} {:>7.3} {:>6.3} {:>5} {:>12}",
            name,
            r.all.found,
            r.all.markers,
            r.all.found_of_reference,
            r.all.reference,
            median,
            max,
            r.all.false_markers.len(),
            ratio.map_or("-".into(), |x| format!("{x:.2}"))
        );
    };
    line(&format!("OpenCV {} stock (set)", set.opencv), &stock5, None);
    let mut details = Vec::new();
    for (k, (name, options)) in levers.iter().enumerate() {
        let mut detector = Detector::with_options(*options)?;
        let stock_pass_detector = StockPass::new()?;
        let (mut report, mut stock) = (Report::default(), Report::default());
        let (mut t_ours, mut t_stock) = (Duration::ZERO, Duration::ZERO);
        // Interleaved image by image, so that load on the machine hits both alike.
        for (v, image) in set.variants.iter().zip(&images) {
            let t = Instant::now();
            let found = detector.detect(image)?;
            t_ours += t.elapsed();
            let t = Instant::now();
            let stock_found = stock_pass(&stock_pass_detector, image, v.mirrored)?;
            t_stock += t.elapsed();
            report.add(v, &found.iter().map(Found::from).collect::<Vec<_>>());
            stock.add(v, &stock_found);
        }
        if k == 0 {
            line("OpenCV 4.6 stock pass", &stock, Some(1.0));
        }
        line(
            name,
            &report,
            Some(t_ours.as_secs_f64() / t_stock.as_secs_f64()),
        );
        if k == ours_row {
            // Why ours misses what it misses and reports what is not there:
            // the candidates OpenCV found at each place and how they read.
            let mut why = Vec::new();
            let lists = [
                ("missed", &report.all.missed),
                ("false", &report.all.false_markers),
            ];
            for (what, list) in lists {
                for (file, id, [x, y]) in list {
                    let image = imgcodecs::imread(set.dir.join(file), imgcodecs::IMREAD_GRAYSCALE)?;
                    let readings = readings_near(&mut detector, &image, [*x, *y])?;
                    why.push(format!(
                        "  {what} id {id} at ({x:.1}, {y:.1}) in {file}: {}",
                        readings.join("; ")
                    ));
                }
            }
            details.push((report, stock, why));
        }
    }
    if let Some((ours, stock, why)) = details.first() {
        println!(
            "\nOurs by variant:\n{}",
            table(&[
                ("ours", ours),
                ("OpenCV 4.6", stock),
                (&format!("OpenCV {}", set.opencv), &stock5)
            ])
        );
        println!("Ours, what went wrong and how the candidates there read:");
        for line in why {
            println!("{line}");
        }
    }
    Ok(())
}
