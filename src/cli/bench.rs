//! `tadgs bench`: the stage table of a training iteration, on the fixed benchmark scene or on a
//! real scene (its images, its population and SH degree, from initialisation or a checkpoint).

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Result, bail};
use tadgs::bench::{BenchReport, benchmark_config, run, time_world};
use tadgs::io::checkpoint::Checkpoint;
use tadgs::scene::{BackendKind, apply_overrides};
use tadgs::train::Trainer;

use super::{backend_kind, checkpoint_and_run, load_dataset, load_with_overrides, set_backend};

/// Options of `tadgs bench`.
#[derive(clap::Args, Clone, Debug)]
pub struct BenchArgs {
    /// Number of Gaussians of the benchmark scene (one or more, comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "100000")]
    pub gaussians: Vec<usize>,
    /// Image sizes of the benchmark scene as WxH (one or more, comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "640x360")]
    pub size: Vec<String>,
    /// Time a real scene instead: its training views, its initial population and the SH
    /// degree and view size its schedule gives at iteration 0.
    #[arg(long, value_name = "FILE.ron", conflicts_with = "checkpoint")]
    pub scene: Option<PathBuf>,
    /// Time a run where its checkpoint left it (DIR: the run folder or its checkpoint/ folder):
    /// its population, SH degree, exposure corrections and iteration, so the view size is
    /// the one its schedule had reached.
    #[arg(long, value_name = "DIR")]
    pub checkpoint: Option<PathBuf>,
    /// Override a setting, as for `train`: of the scene or checkpoint given, else of the
    /// benchmark scene (e.g. `train.gpu_float_atomics=false` times the GPU backend's portable
    /// backward).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
    /// Runs per stage; the median is reported.
    #[arg(long, default_value_t = 5)]
    pub repeats: usize,
    /// Backend: cpu, or gpu (the GPU-resident iteration of `backend: Gpu`, each stage timed
    /// until the device has finished it).
    #[arg(long, value_parser = ["cpu", "gpu"], default_value = "cpu")]
    pub backend: String,
    /// With --backend gpu: also time every GPU kernel (timestamp queries, where the adapter
    /// offers them) and print each stage's device time per kernel.
    #[arg(long)]
    pub kernels: bool,
}

/// `tadgs bench`: one table per (Gaussians, size) pair of the benchmark scene, or one for the
/// scene or checkpoint given.
pub fn bench(args: &BenchArgs) -> Result<()> {
    let backend = backend_kind(&args.backend);
    if args.kernels {
        if backend != BackendKind::Gpu {
            bail!("--kernels times the GPU kernels: give --backend gpu");
        }
        tadgs::gpu::profile::enable();
    }
    println!(
        "CPU: {} threads, SIMD level: {}",
        rayon::current_num_threads(),
        tadgs::raster::simd_level().name()
    );
    if args.scene.is_some() || args.checkpoint.is_some() {
        print_report(args, &real_scene(args, backend)?);
        return Ok(());
    }
    let sizes = args
        .size
        .iter()
        .map(|s| parse_size(s))
        .collect::<Result<Vec<_>>>()?;
    let mut config = benchmark_config(backend);
    apply_overrides(&mut config, &args.overrides)?;
    for &n in &args.gaussians {
        for &(w, h) in &sizes {
            print_report(args, &run(&config, n, w, h, args.repeats)?);
        }
    }
    Ok(())
}

/// Prints `report`, and why the kernel times are missing where --kernels asked for them.
fn print_report(args: &BenchArgs, report: &BenchReport) {
    println!("\n{}", report.table());
    if args.kernels && report.kernels.is_empty() {
        eprintln!(
            "--kernels: no kernel times, the adapter offers no timestamp queries \
             (wgpu feature TIMESTAMP_QUERY)"
        );
    }
}

/// A `WxH` image size.
fn parse_size(s: &str) -> Result<(u32, u32)> {
    let (w, h) = s
        .split_once('x')
        .ok_or_else(|| anyhow::anyhow!("--size {s}: expected WxH, e.g. 640x360"))?;
    let parse = |v: &str| {
        v.parse::<u32>()
            .ok()
            .filter(|&v| v > 0)
            .ok_or_else(|| anyhow::anyhow!("--size {s}: {v} is not a positive integer"))
    };
    Ok((parse(w)?, parse(h)?))
}

/// Times the scene file or checkpoint of `args`.
fn real_scene(args: &BenchArgs, backend: BackendKind) -> Result<BenchReport> {
    let (trainer, label) = match (&args.scene, &args.checkpoint) {
        (Some(path), _) => {
            let mut config = load_with_overrides(path, &args.overrides)?;
            set_backend(&mut config, backend)?;
            let dataset = Arc::new(load_dataset(&config)?);
            let label = format!("scene `{}`, initial population", config.name);
            (Trainer::try_new(&config, dataset)?, label)
        }
        (None, Some(dir)) => {
            let (folder, _) = checkpoint_and_run(dir);
            let mut checkpoint = Checkpoint::load(&folder)?;
            let config = &mut checkpoint.state.scene;
            apply_overrides(config, &args.overrides)?;
            set_backend(config, backend)?;
            let dataset = Arc::new(load_dataset(config)?);
            let label = format!("scene `{}`, checkpoint {}", config.name, folder.display());
            (Trainer::from_checkpoint(&checkpoint, dataset)?, label)
        }
        (None, None) => unreachable!("called with --scene or --checkpoint"),
    };
    Ok(time_world(trainer.world, &label, args.repeats)?)
}
