//! Rendering time per stereo frame by look, over the benchmark's poses.
//! Run: `cargo run --release -p renderer --example render_cost`.

use geometry::sim::{Counts, Facing, SimWorld, generate, nico_noise, nico_scene};
use renderer::Renderer;
use renderer::look::LookName;
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    let data = generate(
        &nico_scene(),
        0,
        &nico_noise(),
        Counts {
            train: 20,
            test: 0,
            direct: 10,
        },
        4,
    )?;
    for look in LookName::ALL {
        let mut renderer =
            Renderer::with_look(SimWorld::nico(0)?, renderer::look::Look::named(look))?;
        let t = Instant::now();
        let mut n = 0;
        for round in 0..5 {
            for (s, facing) in data
                .train
                .iter()
                .map(|s| (s, Facing::Mirror))
                .chain(data.direct.iter().map(|s| (s, Facing::Head)))
            {
                renderer.render_pair(s.joints.as_ref().unwrap(), facing, round)?;
                n += 1;
            }
        }
        println!(
            "{look}: {:.2} ms per stereo frame",
            t.elapsed().as_secs_f64() * 1e3 / n as f64
        );
    }
    Ok(())
}
