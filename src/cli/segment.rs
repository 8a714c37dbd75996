//! `tadgs segment plan|merge`: split a sequence into temporal segments trained as separate
//! runs, and join the trained segments into one model (see [`tadgs::segment`]).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use tadgs::io::checkpoint::STATE_FILE;
use tadgs::io::model::Model;
use tadgs::segment::{BASE_SCENE_FILE, PLAN_FILE, SegmentPlan, settings_difference};

use super::{
    Ui, create_dir, load_dataset, load_scene, load_with_overrides, scene_text, write_atomic,
};

#[derive(clap::Args, Debug)]
pub struct SegmentCommand {
    #[command(subcommand)]
    pub action: SegmentAction,
}

#[derive(clap::Subcommand, Debug)]
pub enum SegmentAction {
    /// Split a scene's sequence into overlapping segments: writes one scene file per segment
    /// (train each with `tadgs train DIR/segment-K.ron`, on any machine that sees DIR), the
    /// whole-sequence scene and plan.ron. With --slurm, also a Slurm job array and a merge job.
    Plan(PlanArgs),
    /// Train segment K of a plan: `tadgs train DIR/segment-K.ron`, or `tadgs train --resume`
    /// when it has a checkpoint, or nothing when it is trained already; what a cluster task
    /// runs (the Slurm array and the Ray driver), safe to run again after a failure.
    Train(SegmentTrainArgs),
    /// Join the trained segments of a plan into one model of the whole sequence, a run folder
    /// that `eval`, `render`, `export` and `view` take like any other.
    Merge(MergeArgs),
}

#[derive(clap::Args, Debug)]
pub struct SegmentTrainArgs {
    /// The plan: DIR/plan.ron or its folder DIR.
    pub plan: PathBuf,
    /// Which segment, from 0.
    #[arg(long, value_name = "K")]
    pub segment: usize,
    /// Further `tadgs train` options, after `--` (e.g. `-- --masks DIR --checkpoint-every
    /// 500`); settings that change the training make the merge refuse the segment.
    #[arg(last = true, value_name = "TRAIN_ARGS")]
    pub train_args: Vec<String>,
}

/// `tadgs train`'s arguments parsed on their own.
#[derive(clap::Parser, Debug)]
struct TrainOnly {
    #[command(flatten)]
    train: super::train::TrainCommand,
}

#[derive(clap::Args, Debug)]
// Negative numbers are values (and refused with a clear message), not unknown flags.
#[command(allow_negative_numbers = true)]
pub struct PlanArgs {
    /// The scene file of the whole sequence.
    pub scene: PathBuf,
    /// Number of segments.
    #[arg(long, value_name = "N")]
    pub segments: usize,
    /// Frames each segment trains beyond its own on each side (shared with its neighbour).
    #[arg(long, default_value_t = 5, value_name = "FRAMES")]
    pub overlap: usize,
    /// Width of the cross-fade between neighbours in the merged model, in frames: by default
    /// the whole overlap (2·overlap + 1, the most allowed); 1 gives every frame to one segment
    /// and blends only between frames.
    #[arg(long, value_name = "FRAMES")]
    pub fade: Option<f32>,
    /// Train each segment N iterations, the scene's schedule stretched as `tadgs train
    /// --iterations` does.
    #[arg(long, value_name = "N")]
    pub iterations: Option<u32>,
    /// Override a scene setting for every segment (RON value), e.g.
    /// --set densify.max_gaussians=200000. Repeatable.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
    /// The plan folder to write (must not hold a plan yet).
    #[arg(long, short, value_name = "DIR")]
    pub output: PathBuf,
    /// Also write a Slurm job array (one task per segment) and a merge job depending on it:
    /// DIR/slurm/submit.sh submits both.
    #[arg(long)]
    pub slurm: bool,
    /// CPUs per Slurm array task (`#SBATCH --cpus-per-task`).
    #[arg(long, default_value_t = 8, value_name = "N", requires = "slurm")]
    pub slurm_cpus: u32,
    /// Time limit of each Slurm task (`#SBATCH --time`, e.g. 02:00:00); none by default.
    #[arg(long, value_name = "TIME", requires = "slurm")]
    pub slurm_time: Option<String>,
}

#[derive(clap::Args, Debug)]
pub struct MergeArgs {
    /// The plan: DIR/plan.ron or its folder DIR.
    pub plan: PathBuf,
    /// The run folder to write the merged model into (default DIR/merged).
    #[arg(long, short, value_name = "DIR")]
    pub output: Option<PathBuf>,
    /// Replace a merged model already in the output folder (its evaluation, renders and
    /// report go with it).
    #[arg(long)]
    pub force: bool,
}

pub fn segment(command: SegmentCommand, ui: Ui) -> Result<()> {
    match command.action {
        SegmentAction::Plan(args) => plan(args),
        SegmentAction::Train(args) => train_segment(args, ui),
        SegmentAction::Merge(args) => merge(args),
    }
}

/// The plan file and its folder, given the file or the folder.
fn read_plan(path: &Path) -> Result<(PathBuf, SegmentPlan)> {
    let file = if path.is_dir() {
        path.join(PLAN_FILE)
    } else {
        path.to_path_buf()
    };
    let dir = file.parent().unwrap_or(Path::new(".")).to_path_buf();
    let text = std::fs::read_to_string(&file)
        .with_context(|| format!("reading the plan {}", file.display()))?;
    let plan: SegmentPlan =
        ron::from_str(&text).map_err(|e| anyhow::anyhow!("{}:{e}", file.display()))?;
    plan.validate()
        .with_context(|| format!("checking {}", file.display()))?;
    Ok((dir, plan))
}

fn train_segment(args: SegmentTrainArgs, ui: Ui) -> Result<()> {
    let (dir, plan) = read_plan(&args.plan)?;
    let Some(segment) = plan.segments.get(args.segment) else {
        bail!(
            "--segment {}: the plan has segments 0 to {}",
            args.segment,
            plan.segments.len() - 1
        );
    };
    let run = segment.run_folder(&dir);
    if run.join("model.safetensors").is_file() {
        println!("{} is trained already", run.display());
        return Ok(());
    }
    let mut argv: Vec<std::ffi::OsString> = vec!["train".into()];
    if run.join("checkpoint").join(STATE_FILE).is_file() {
        argv.extend(["--resume".into(), run.into_os_string()]);
    } else {
        // A folder without a checkpoint holds at most the start of a failed attempt.
        argv.push(segment.scene_file(&dir).into_os_string());
        argv.push("--force".into());
    }
    argv.extend(args.train_args.into_iter().map(Into::into));
    let command = <TrainOnly as clap::Parser>::try_parse_from(argv).map_err(|e| {
        let message = e.to_string();
        anyhow::anyhow!(
            "the train options after `--`: {}",
            message
                .lines()
                .next()
                .unwrap_or_default()
                .trim_start_matches("error: ")
        )
    })?;
    super::train::train(command.train, ui)
}

fn plan(args: PlanArgs) -> Result<()> {
    let mut base = load_with_overrides(&args.scene, &args.overrides)?;
    if let Some(n) = args.iterations {
        super::train::set_iterations(&mut base, n, &args.overrides)?;
    }
    if base.segment.is_some() {
        bail!(
            "{} already trains a segment (`segment: Some(…)`): plan from the whole-sequence scene",
            args.scene.display()
        );
    }
    let dir = &args.output;
    if dir.join(PLAN_FILE).exists() {
        bail!(
            "{} already holds a plan: choose another folder (or delete it)",
            dir.display()
        );
    }
    let dataset = load_dataset(&base)?;
    let fade = args.fade.unwrap_or(2.0 * args.overlap as f32 + 1.0);
    let plan = SegmentPlan::new(dataset.frame_count, args.segments, args.overlap, fade)?;
    create_dir(dir)?;
    let dir = std::path::absolute(dir).with_context(|| format!("resolving {}", dir.display()))?;
    base.absolute_paths();
    base.output = dir.join("merged").to_string_lossy().into_owned();
    write_atomic(&dir.join(BASE_SCENE_FILE), scene_text(&base)?.as_bytes())?;
    for (index, segment) in plan.segments.iter().enumerate() {
        let scene = plan.segment_scene(&base, index, &segment.run_folder(&dir));
        let path = segment.scene_file(&dir);
        write_atomic(&path, scene_text(&scene)?.as_bytes())?;
        println!(
            "{}: frames {} to {} (draws {} to {})",
            path.display(),
            segment.first_frame,
            segment.last_frame,
            segment.owned_first,
            segment.owned_last
        );
    }
    let plan_path = dir.join(PLAN_FILE);
    let text = ron::ser::to_string_pretty(&plan, ron::ser::PrettyConfig::default())?;
    write_atomic(&plan_path, text.as_bytes())?;
    println!(
        "{} segments of {} frames: {}",
        plan.segments.len(),
        plan.frame_count,
        plan_path.display()
    );
    if args.slurm {
        let tadgs = std::env::current_exe().context("finding the tadgs binary")?;
        let scripts = slurm_scripts(&dir, &plan, &base.name, &tadgs, &args);
        let slurm = dir.join("slurm");
        create_dir(&slurm)?;
        create_dir(&dir.join("logs"))?;
        for (name, text) in &scripts {
            let path = slurm.join(name);
            write_atomic(&path, text.as_bytes())?;
            make_executable(&path)?;
        }
        println!(
            "Slurm: submit with `bash {}`",
            slurm.join("submit.sh").display()
        );
    } else {
        println!(
            "train each segment with `tadgs train {}` (K = 0 to {}), then `tadgs segment merge {}`",
            dir.join("segment-K.ron").display(),
            plan.segments.len() - 1,
            plan_path.display()
        );
    }
    Ok(())
}

/// The Slurm scripts of a plan: `segments.sbatch` (a job array, one task per segment, each
/// starting its run or resuming it from its checkpoint when Slurm requeues it),
/// `merge.sbatch`, and `submit.sh`, which submits the merge to run after the whole array
/// succeeded. `$TADGS` overrides the binary's path.
fn slurm_scripts(
    dir: &Path,
    plan: &SegmentPlan,
    name: &str,
    tadgs: &Path,
    args: &PlanArgs,
) -> Vec<(&'static str, String)> {
    let quote = |path: &Path| shell_quote(&path.to_string_lossy());
    let job = shell_safe(name);
    let mut array = String::new();
    writeln!(array, "#!/bin/bash").unwrap();
    writeln!(array, "#SBATCH --job-name=tadgs-{job}").unwrap();
    writeln!(array, "#SBATCH --array=0-{}", plan.segments.len() - 1).unwrap();
    writeln!(array, "#SBATCH --cpus-per-task={}", args.slurm_cpus).unwrap();
    if let Some(time) = &args.slurm_time {
        writeln!(array, "#SBATCH --time={}", shell_safe(time)).unwrap();
    }
    writeln!(array, "#SBATCH --requeue").unwrap();
    writeln!(array, "#SBATCH --output={}/logs/%x-%a.log", dir.display()).unwrap();
    let body = format!(
        "set -euo pipefail\n\
         # One segment per array task, trained (or resumed, when Slurm runs the task again).\n\
         default_tadgs={tadgs}\n\
         export RAYON_NUM_THREADS=\"${{SLURM_CPUS_PER_TASK:-{cpus}}}\"\n\
         \"${{TADGS:-$default_tadgs}}\" segment train {plan} --segment \"$SLURM_ARRAY_TASK_ID\"\n",
        tadgs = quote(tadgs),
        plan = quote(&dir.join(PLAN_FILE)),
        cpus = args.slurm_cpus,
    );
    array.push_str(&body);

    let mut merge = String::new();
    writeln!(merge, "#!/bin/bash").unwrap();
    writeln!(merge, "#SBATCH --job-name=tadgs-{job}-merge").unwrap();
    writeln!(merge, "#SBATCH --cpus-per-task=1").unwrap();
    writeln!(merge, "#SBATCH --output={}/logs/%x.log", dir.display()).unwrap();
    write!(
        merge,
        "set -euo pipefail\n\
         default_tadgs={tadgs}\n\
         \"${{TADGS:-$default_tadgs}}\" segment merge {plan} --force\n",
        tadgs = quote(tadgs),
        plan = quote(&dir.join(PLAN_FILE)),
    )
    .unwrap();

    let slurm = dir.join("slurm");
    let submit = format!(
        "#!/bin/bash\n\
         # Submits the segments' job array, then the merge to run once every task succeeded.\n\
         set -euo pipefail\n\
         array=$(sbatch --parsable {array})\n\
         sbatch --dependency=afterok:\"${{array%%;*}}\" {merge}\n",
        array = quote(&slurm.join("segments.sbatch")),
        merge = quote(&slurm.join("merge.sbatch")),
    );
    vec![
        ("segments.sbatch", array),
        ("merge.sbatch", merge),
        ("submit.sh", submit),
    ]
}

/// `text` in single quotes for bash.
fn shell_quote(text: &str) -> String {
    format!("'{}'", text.replace('\'', r"'\''"))
}

/// `text` with every character outside `[A-Za-z0-9._:-]` replaced by `_` (for sbatch
/// directives, which are not shell-parsed).
fn shell_safe(text: &str) -> String {
    text.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || "._:-".contains(c) {
                c
            } else {
                '_'
            }
        })
        .collect()
}

#[cfg(unix)]
fn make_executable(path: &Path) -> Result<()> {
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o755))
        .with_context(|| format!("making {} executable", path.display()))
}

#[cfg(not(unix))]
fn make_executable(_path: &Path) -> Result<()> {
    Ok(())
}

fn merge(args: MergeArgs) -> Result<()> {
    let (dir, plan) = read_plan(&args.plan)?;
    let mut base = load_scene(&dir.join(BASE_SCENE_FILE))?;
    let mut models = Vec::with_capacity(plan.segments.len());
    for (index, segment) in plan.segments.iter().enumerate() {
        let run = segment.run_folder(&dir);
        let model_path = run.join("model.safetensors");
        if !model_path.is_file() {
            if run.join("checkpoint").join(STATE_FILE).is_file() {
                bail!(
                    "segment {index}: {} has not finished (no model.safetensors): continue it \
                     with `tadgs train --resume {}`",
                    run.display(),
                    run.display()
                );
            }
            bail!(
                "segment {index}: {} has no trained model: train it with `tadgs train {}`",
                run.display(),
                segment.scene_file(&dir).display()
            );
        }
        let trained = load_scene(&run.join("scene.ron"))?;
        let expected = plan.segment_scene(&base, index, &run);
        if let Some(difference) = settings_difference(&expected, &trained) {
            bail!(
                "segment {index}: {} was trained with other settings than the plan's \
                 ({difference}); train it again from {}",
                run.display(),
                segment.scene_file(&dir).display()
            );
        }
        models.push(Model::load(&model_path)?);
    }
    let merged = plan.merge(&models)?;
    let output = args.output.unwrap_or_else(|| dir.join("merged"));
    let model_path = output.join("model.safetensors");
    if model_path.exists() && !args.force {
        bail!(
            "{} already holds a model: pass --force to replace it, or choose another folder \
             with -o DIR",
            output.display()
        );
    }
    let _lock = super::run_folder::RunLock::acquire(&output)?;
    // A replaced model takes the evaluation, renders and report of the old one with it.
    super::run_folder::remove_run_outputs(&output)?;
    base.output = std::path::absolute(&output)
        .unwrap_or_else(|_| output.clone())
        .to_string_lossy()
        .into_owned();
    write_atomic(&output.join("scene.ron"), scene_text(&base)?.as_bytes())?;
    merged.save(&model_path)?;
    println!(
        "{} segments, {} Gaussians over {} frames: {}",
        plan.segments.len(),
        merged.gaussians.len(),
        plan.frame_count,
        output.display()
    );
    Ok(())
}
