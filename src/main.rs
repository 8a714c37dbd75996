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
    /// Time every stage of a training iteration and print a table: on the fixed benchmark
    /// scene, or on a real scene (--scene) or run (--checkpoint) at its own size.
    Bench(cli::bench::BenchArgs),
    /// Serve an interactive 4D viewer in the browser for a run, a model file or a splat PLY:
    /// orbit, pan and zoom, a time slider, dataset cameras; frames rendered by tadgs itself.
    View(cli::view::ViewCommand),
    /// Long sequences: split a scene into temporal segments trained as separate runs (on one
    /// machine or a cluster, e.g. a Slurm job array), then merge them into one model.
    Segment(cli::segment::SegmentCommand),
}

fn main() -> std::process::ExitCode {
    quiet_wayland_probe();
    match run(Cli::parse()) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(error) => {
            if let Some(stopped) = error.downcast_ref::<cli::train::Stopped>() {
                eprintln!("{stopped}");
                return std::process::ExitCode::from(130);
            }
            eprintln!("error: {}", describe(&error));
            std::process::ExitCode::FAILURE
        }
    }
}

/// Mesa's Vulkan driver probes for a Wayland display when a GPU adapter opens and, on a machine
/// without a desktop session, prints "XDG_RUNTIME_DIR is invalid or not set in the environment"
/// twice. tadgs never opens a window, so any absolute folder satisfies the probe, which then
/// finds no display and stays quiet.
fn quiet_wayland_probe() {
    if std::env::var_os("XDG_RUNTIME_DIR").is_none() {
        // SAFETY: called first thing in `main`, before any other thread exists.
        unsafe { std::env::set_var("XDG_RUNTIME_DIR", std::env::temp_dir()) };
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
        // Colours only on a terminal (not in log files or pipes), and never with NO_COLOR.
        .with_ansi(
            std::io::IsTerminal::is_terminal(&std::io::stderr())
                && std::env::var_os("NO_COLOR").is_none(),
        )
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
        Command::Bench(args) => cli::bench::bench(&args),
        Command::View(args) => cli::view::view(args, ui),
        Command::Segment(args) => cli::segment::segment(args, ui),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    fn parse(args: &[&str]) -> Cli {
        let mut full = vec!["tadgs"];
        full.extend_from_slice(args);
        Cli::try_parse_from(full).unwrap_or_else(|e| panic!("{args:?}: {e}"))
    }

    /// The clap definition is consistent (no clashing names, defaults that parse).
    #[test]
    fn command_definition_is_valid() {
        Cli::command().debug_assert();
    }

    /// Property: every option documented by `--help` is accepted and lands in its field.
    #[test]
    fn every_documented_option_parses() {
        let cli = parse(&[
            "-vv",
            "--quiet",
            "train",
            "s.ron",
            "--iterations",
            "50",
            "--set",
            "a.b=1",
            "--set",
            "c=2",
            "--output",
            "out",
            "--checkpoint-every",
            "10",
            "--until",
            "20",
            "--eval-every",
            "5",
            "--no-report",
            "--lpips",
            "w.safetensors",
            "--masks",
            "m",
            "--flow-threshold",
            "0.5",
            "--no-renders",
        ]);
        assert_eq!((cli.verbose, cli.quiet), (2, true));
        let Command::Train(t) = cli.command else {
            panic!("train")
        };
        assert_eq!(t.scene.as_deref(), Some(std::path::Path::new("s.ron")));
        assert_eq!(t.iterations, Some(50));
        assert_eq!(t.overrides, ["a.b=1", "c=2"]);
        assert_eq!(t.output.as_deref(), Some(std::path::Path::new("out")));
        assert_eq!(
            (t.checkpoint_every, t.until, t.eval_every),
            (Some(10), Some(20), Some(5))
        );
        assert!(t.no_report && t.eval.no_renders);
        assert_eq!(t.eval.flow_threshold, 0.5);
        assert!(t.eval.lpips.is_some() && t.eval.masks.is_some());

        let Command::Train(t) = parse(&["train", "--resume", "runs/x", "-o", "o"]).command else {
            panic!("train")
        };
        assert!(t.scene.is_none() && t.resume.is_some());

        let Command::Eval(e) = parse(&[
            "eval",
            "run",
            "--set",
            "k=v",
            "--split",
            "train",
            "--lpips",
            "w",
            "--masks",
            "m",
            "--flow-threshold",
            "2",
            "--no-renders",
        ])
        .command
        else {
            panic!("eval")
        };
        assert_eq!(e.split, cli::eval::Split::Train);
        assert_eq!(e.overrides, ["k=v"]);

        let Command::Render(r) = parse(&[
            "render",
            "run",
            "--orbit",
            "--frames",
            "12",
            "--time",
            "0.5",
            "--output",
            "v.mp4",
            "--fps",
            "24",
            "--background",
            "1,1,1",
            "--size",
            "320x240",
            "--up",
            "0,1,0",
            "--distance",
            "0.8",
            "--set",
            "k=v",
        ])
        .command
        else {
            panic!("render")
        };
        assert!(r.cameras.orbit);
        assert_eq!((r.frames, r.time, r.fps), (Some(12), Some(0.5), 24.0));
        assert_eq!(r.background, Some([1.0, 1.0, 1.0]));
        assert_eq!(r.size, Some((320, 240)));
        assert_eq!(r.up, Some(glam::Vec3::Y));
        assert_eq!(r.distance, 0.8);
        for (args, check) in [
            (vec!["render", "m.ply", "--heldout"], 0),
            (vec!["render", "m.ply", "--heldout", "3"], 1),
            (vec!["render", "m.ply", "--camera", "c.ron"], 2),
            (vec!["render", "m.ply", "--path", "p.ron"], 3),
        ] {
            let Command::Render(r) = parse(&args).command else {
                panic!("render")
            };
            match check {
                0 => assert_eq!(r.cameras.heldout, Some(-1)),
                1 => assert_eq!(r.cameras.heldout, Some(3)),
                2 => assert!(r.cameras.camera.is_some()),
                _ => assert!(r.cameras.path.is_some()),
            }
        }

        let Command::Export(x) = parse(&[
            "export",
            "run",
            "--format",
            "ply",
            "--times",
            "0,0.5",
            "--frames",
            "1,2",
            "--every-frame",
            "--min-opacity",
            "0.01",
            "-o",
            "out",
            "--set",
            "k=v",
        ])
        .command
        else {
            panic!("export")
        };
        assert_eq!(x.times, [0.0, 0.5]);
        assert_eq!(x.frames, [1, 2]);
        assert!(x.every_frame);
        assert_eq!(x.min_opacity, 0.01);
        let Command::Export(x) = parse(&["export", "run", "--format", "4d"]).command else {
            panic!("export")
        };
        assert_eq!(x.format, cli::export::ExportFormat::FourD);

        let Command::Masks(m) = parse(&[
            "masks",
            "s.ron",
            "--set",
            "k=v",
            "--output",
            "m",
            "--flow-threshold",
            "1.5",
        ])
        .command
        else {
            panic!("masks")
        };
        assert_eq!(m.flow_threshold, 1.5);

        let Command::View(v) = parse(&[
            "view",
            "run",
            "--host",
            "0.0.0.0",
            "--port",
            "8080",
            "--background",
            "1,1,1",
            "--up",
            "0,1,0",
            "--backend",
            "gpu",
            "--no-data",
            "--set",
            "k=v",
        ])
        .command
        else {
            panic!("view")
        };
        assert_eq!((v.host.to_string(), v.port), ("0.0.0.0".to_string(), 8080));
        assert_eq!((v.backend.as_str(), v.no_data), ("gpu", true));
        assert_eq!(v.up, Some(glam::Vec3::Y));
        let Command::Train(t) = parse(&["train", "s.ron", "--view", "--view-port", "9000"]).command
        else {
            panic!("train")
        };
        assert_eq!((t.view, t.view_port), (true, 9000));

        let Command::Info(i) = parse(&["info", "s.ron", "--set", "k=v", "--data"]).command else {
            panic!("info")
        };
        assert!(i.data);
    }

    /// Property: contradictory or malformed options are refused by the parser.
    #[test]
    fn bad_options_are_refused() {
        for args in [
            vec!["tadgs", "train"],
            vec!["tadgs", "train", "s.ron", "--resume", "r"],
            vec!["tadgs", "render", "m", "--orbit", "--camera", "c.ron"],
            vec!["tadgs", "render", "m", "--size", "640"],
            vec!["tadgs", "render", "m", "--background", "2,0,0"],
            vec!["tadgs", "export", "m", "--format", "obj"],
            vec!["tadgs", "view", "m", "--host", "localhost:80"],
            vec!["tadgs", "train", "s.ron", "--view-port", "9000"],
        ] {
            assert!(Cli::try_parse_from(&args).is_err(), "{args:?} parsed");
        }
    }

    /// Every command's help explains each of its options (no option without help text).
    #[test]
    fn every_option_has_help() {
        let cli = Cli::command();
        for command in cli.get_subcommands() {
            for arg in command.get_arguments() {
                assert!(
                    arg.get_help().is_some(),
                    "{} --{:?} has no help",
                    command.get_name(),
                    arg.get_long()
                );
            }
        }
    }
}
