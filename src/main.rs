//! The `tadgs` command line: train a scene, evaluate, render and export a trained model,
//! compute dynamic masks, inspect scenes, runs and models. Each command lives in `src/cli/`.

mod cli;

use clap::{Parser, Subcommand};

/// Dynamic (4D) Gaussian splatting with temporally aware densification (VAD, TAT, TOW).
///
/// A run folder (`--output`, default the scene's `output`) holds: scene.ron (the resolved
/// settings), model.safetensors (every Gaussian's parameters), metrics.json / metrics.csv
/// (per held-out view and means), heldout/ (render | ground truth PNGs), masks/ (the dynamic
/// masks used by M-PSNR and M-SSIM), checkpoint/ (to continue with `train --resume`) and
/// report/index.html (plots of the run).
#[derive(Parser, Debug)]
#[command(version, about, long_about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// More log output (-v: debug, -vv: trace). RUST_LOG, when set, takes precedence.
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    verbose: u8,
    /// No progress bars and no informational logs: only warnings, errors and the final
    /// summary (for scripts).
    #[arg(short, long, global = true)]
    quiet: bool,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Train on a scene file (or continue a checkpoint), save the model, evaluate every
    /// held-out view and write the run report.
    Train(cli::train::TrainCommand),
    /// Evaluate a trained run: render every held-out view and write PSNR, SSIM, LPIPS,
    /// M-PSNR and M-SSIM per view and on average (metrics.json, metrics.csv).
    Eval(cli::eval::EvalCommand),
    /// Render images or a video of a run, a model file or a splat PLY along a camera path: an
    /// orbit, a dataset camera over time, one camera or a path from a RON file.
    Render(cli::render::RenderCommand),
    /// Export a run or model: per-frame PLY files in the standard 3DGS layout, or the
    /// self-contained 4D model file.
    Export(cli::export::ExportCommand),
    /// Compute the dynamic masks of a scene's held-out views (optical flow between frames t−5
    /// and t of each test camera) and save them as PNGs, for reuse by `train` and `eval`.
    Masks(cli::eval::MasksCommand),
    /// Describe a scene file (resolved settings), a run folder, a model, a splat PLY or a
    /// checkpoint.
    Info(cli::info::InfoCommand),
}

fn main() -> std::process::ExitCode {
    match run(Cli::parse()) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("error: {}", describe(&error));
            std::process::ExitCode::FAILURE
        }
    }
}

/// The error and its causes on one line, skipping causes the message already quotes.
fn describe(error: &anyhow::Error) -> String {
    let mut text = error.to_string();
    for cause in error.chain().skip(1) {
        let cause = cause.to_string();
        if !text.contains(&cause) {
            text = format!("{text}: {cause}");
        }
    }
    text
}

fn run(cli: Cli) -> anyhow::Result<()> {
    let level = match (cli.quiet, cli.verbose) {
        (true, _) => "warn",
        (false, 0) => "info",
        (false, 1) => "debug",
        _ => "trace",
    };
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| level.into()),
        )
        .with_target(false)
        .without_time()
        .with_writer(std::io::stderr)
        .init();
    let ui = cli::Ui { quiet: cli.quiet };
    match cli.command {
        Command::Train(args) => cli::train::train(args, ui),
        Command::Eval(args) => cli::eval::eval(args, ui),
        Command::Render(args) => cli::render::render(args, ui),
        Command::Export(args) => cli::export::export(args, ui),
        Command::Masks(args) => cli::eval::masks(args, ui),
        Command::Info(args) => cli::info::info(args),
    }
}
