//! `cargo xtask web [--serve]`: the try-on page into `web/dist/` — the sartor-web module for
//! the WebAssembly target named in `rust-toolchain.toml`, its JavaScript glue from
//! wasm-bindgen's own generator (`wasm-bindgen-cli-support`, pinned in the workspace to the
//! `wasm-bindgen` crate's version, as the glue must be), the page's sources, and the assets it
//! loads: every shipped model (`datasets/models/*`: the T-shirt at 4,210 and 8,710 triangles)
//! with its weight matrices in f16 (and without the linear baseline, which the page does not
//! use), the body, the walk cycle and a few CMU clips. `--serve` then serves the folder on
//! 127.0.0.1.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, ensure};
use sartor_runtime::{GarmentModel, TensorStorage};
use serde::Serialize;

/// The stored CMU clips the page offers, labelled by their subject's theme (CMU subjects 05:
/// modern dance, 06: basketball, 07: walks, 09: runs).
pub const PAGE_CLIPS: [(&str, &str); 4] = [
    ("cmu/07_01", "CMU 07_01: walk"),
    ("cmu/05_06", "CMU 05_06: modern dance"),
    ("cmu/09_01", "CMU 09_01: run"),
    ("cmu/06_01", "CMU 06_01: basketball"),
];

/// The procedural clips the page offers (computed in the page, nothing downloaded).
pub const PAGE_PROCEDURAL: [&str; 3] = ["dance_disco", "jumping_jacks", "walk_normal"];

/// Arguments of `web`.
#[derive(clap::Args, Debug)]
pub struct WebArgs {
    /// Serve web/dist on 127.0.0.1 after building it.
    #[arg(long)]
    pub serve: bool,
    /// Port to serve on (0: any free port).
    #[arg(long, default_value_t = 8000)]
    pub port: u16,
    /// Serve web/dist as it is, without building it.
    #[arg(long)]
    pub no_build: bool,
}

#[derive(Serialize)]
struct Manifest {
    procedural: Vec<String>,
    clips: Vec<ManifestClip>,
    /// The garment models the page offers, fewest triangles first (the page loads the first,
    /// the others when chosen), each in `models/<name>/`.
    models: Vec<ModelInfo>,
    /// The shipped models' experiments' `simulation.arm_clearance` (the same in each: checked)
    /// with the legs held too (`sartor_motion::LEG_CLEARANCE_M`, as `sartor demo`): the page
    /// holds the arms out of the torso as the training motions did, and the legs (`null`: the
    /// experiments held nothing, neither does the page).
    arm_clearance: Option<sartor_motion::ClearanceOptions>,
}

#[derive(Serialize)]
struct ManifestClip {
    name: String,
    label: String,
}

#[derive(Serialize)]
struct ModelInfo {
    /// The shipped model's folder name (`datasets/models/<name>`, `models/<name>/` here).
    name: String,
    garment: String,
    triangles: usize,
    storage: &'static str,
    f32_bytes: u64,
    page_bytes: u64,
}

/// Build (unless `--no-build`) and serve (with `--serve`).
pub fn web(args: &WebArgs, root: &Path) -> anyhow::Result<()> {
    let root = &root
        .canonicalize()
        .with_context(|| format!("{}", root.display()))?;
    let dist = root.join("web/dist");
    if !args.no_build {
        build(root, &dist)?;
    }
    if args.serve {
        ensure!(
            dist.join("index.html").is_file(),
            "{} has no index.html: run `cargo xtask web` first",
            dist.display()
        );
        let server = sartor_web::serve_dir(&dist, args.port)
            .with_context(|| format!("serving {} on port {}", dist.display(), args.port))?;
        println!(
            "serving {} at {} (Ctrl-C stops)",
            dist.display(),
            server.url()
        );
        loop {
            std::thread::park();
        }
    }
    Ok(())
}

/// The WebAssembly target of `rust-toolchain.toml` (its `targets` list).
fn wasm_target(root: &Path) -> anyhow::Result<String> {
    let path = root.join("rust-toolchain.toml");
    let text = std::fs::read_to_string(&path).with_context(|| format!("{}", path.display()))?;
    text.lines()
        .filter(|l| l.trim_start().starts_with("targets"))
        .flat_map(|l| l.split('"'))
        .find(|t| t.starts_with("wasm32"))
        .map(str::to_string)
        .with_context(|| format!("{} lists no wasm32 target in `targets`", path.display()))
}

fn target_dir(root: &Path) -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR").map_or_else(|| root.join("target"), PathBuf::from)
}

fn run(command: &mut Command) -> anyhow::Result<()> {
    let status = command
        .status()
        .with_context(|| format!("running {command:?}"))?;
    ensure!(status.success(), "{command:?} failed ({status})");
    Ok(())
}

/// The page's JavaScript glue and final module from the module cargo built, into `out`: what
/// `wasm-bindgen --target web --no-typescript --out-dir <out> <wasm>` of the same version
/// writes (the same options; byte for byte the same files with walrus at 0.27.2, as the
/// command's own lock has it: the module's producers section names walrus's version), from the
/// generator that command wraps. It is built with xtask instead of installed with `cargo
/// install wasm-bindgen-cli`, which compiled the command's other needs too (its test runner's
/// server and downloads, its arguments, logging): 92 to 110 s on the 2-core AMD EPYC Zen 3 VM,
/// on every fresh machine.
fn bindgen(wasm: &Path, out: &Path) -> anyhow::Result<()> {
    let start = Instant::now();
    let mut b = wasm_bindgen_cli_support::Bindgen::new();
    b.web(true)?;
    // The command's defaults where they differ from the library's: a default module path in
    // the glue's `init` (the page calls it without one), and no externref unless the module
    // asks (the command passes its deprecated flag's `false`, over the environment's).
    #[allow(deprecated)]
    b.input_path(wasm)
        .typescript(false)
        .omit_default_module_path(false)
        .reference_types(false);
    b.generate(out).with_context(|| {
        format!(
            "generating the glue of {} into {}",
            wasm.display(),
            out.display()
        )
    })?;
    println!(
        "generated the page's glue in {:.1} s",
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

fn copy(from: &Path, to: &Path) -> anyhow::Result<u64> {
    if let Some(dir) = to.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    std::fs::copy(from, to)
        .with_context(|| format!("copying {} to {}", from.display(), to.display()))
}

/// Every file of `from` (recursively, but not `dist/`) into `to`.
fn copy_sources(from: &Path, to: &Path) -> anyhow::Result<()> {
    for entry in std::fs::read_dir(from).with_context(|| format!("{}", from.display()))? {
        let path = entry?.path();
        let name = path.file_name().unwrap_or_default();
        if path.is_dir() {
            if name != "dist" {
                copy_sources(&path, &to.join(name))?;
            }
        } else {
            copy(&path, &to.join(name))?;
        }
    }
    Ok(())
}

fn build(root: &Path, dist: &Path) -> anyhow::Result<()> {
    let target = wasm_target(root)?;
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let start = Instant::now();
    run(Command::new(&cargo)
        .current_dir(root)
        .args([
            "build",
            "--release",
            "-p",
            "sartor-web",
            "--lib",
            "--target",
        ])
        .arg(&target))?;
    println!(
        "built sartor-web for {target} in {:.0} s",
        start.elapsed().as_secs_f64()
    );
    if dist.exists() {
        std::fs::remove_dir_all(dist).with_context(|| format!("removing {}", dist.display()))?;
    }
    let wasm = target_dir(root)
        .join(&target)
        .join("release")
        .join("sartor_web.wasm");
    bindgen(&wasm, &dist.join("pkg"))?;
    copy_sources(&root.join("web"), dist)?;

    // Assets: the models in f16 without the linear baseline, the body, the motions.
    let data = sartor_pipeline::DataDir::new(root)?;
    let model_dirs = data
        .shipped_model_dirs()
        .with_context(|| format!("listing {}", data.models_dir().display()))?;
    ensure!(
        !model_dirs.is_empty(),
        "{} holds no shipped model",
        data.models_dir().display()
    );
    let mut models = Vec::new();
    let mut arm_clearance = None;
    for model_dir in &model_dirs {
        let (info, clearance) = page_model(model_dir, root, dist)?;
        match &arm_clearance {
            None => arm_clearance = Some((clearance, model_dir)),
            Some((first, first_dir)) => ensure!(
                *first == clearance,
                "{} and {} were trained with different arm clearances: the page holds the arms \
                 once for every garment",
                first_dir.display(),
                model_dir.display()
            ),
        }
        models.push(info);
    }
    models.sort_by_key(|m| m.triangles);
    let arm_clearance = arm_clearance
        .and_then(|(c, _)| c)
        .map(sartor_motion::ClearanceOptions::with_player_legs);
    let body_dir = root.join("datasets/body/makehuman");
    for file in [
        "model.json",
        "model.safetensors",
        "phenotype.json",
        "phenotype.safetensors",
        "tpose.json",
    ] {
        copy(&body_dir.join(file), &dist.join("body").join(file))?;
    }
    let motions = root.join("datasets/motions");
    copy(&motions.join("walk.json"), &dist.join("motions/walk.json"))?;
    for (clip, _) in PAGE_CLIPS {
        for ext in ["json", "safetensors"] {
            let file = format!("{clip}.{ext}");
            copy(&motions.join(&file), &dist.join("motions").join(&file))?;
        }
    }
    for file in ["README.md", "PROVENANCE.md"] {
        copy(
            &motions.join("cmu").join(file),
            &dist.join("motions/cmu").join(file),
        )?;
    }
    let manifest = Manifest {
        procedural: PAGE_PROCEDURAL.iter().map(|s| s.to_string()).collect(),
        clips: PAGE_CLIPS
            .iter()
            .map(|(name, label)| ManifestClip {
                name: name.to_string(),
                label: label.to_string(),
            })
            .collect(),
        models,
        arm_clearance,
    };
    let json = serde_json::to_string_pretty(&manifest)?;
    std::fs::write(dist.join("manifest.json"), json)?;
    let total: u64 = walk(dist)?.iter().map(|p| size(p)).sum();
    let models: Vec<String> = manifest
        .models
        .iter()
        .map(|m| {
            format!(
                "{} {:.1} MB in f16, {:.1} MB in f32",
                m.garment,
                m.page_bytes as f64 / 1e6,
                m.f32_bytes as f64 / 1e6
            )
        })
        .collect();
    println!(
        "wrote {} ({:.1} MB; models: {})",
        dist.display(),
        total as f64 / 1e6,
        models.join("; ")
    );
    Ok(())
}

fn size(path: &Path) -> u64 {
    std::fs::metadata(path).map(|m| m.len()).unwrap_or(0)
}

/// The shipped model in `model_dir` as the page loads it, into `<dist>/models/<name>/`: its
/// weight matrices in f16, without the linear baseline, and its binding. Returns what the
/// manifest says of it, and the arm clearance of the experiment it came from (its
/// `pipeline.json`'s config, `simulation.arm_clearance`).
fn page_model(
    model_dir: &Path,
    root: &Path,
    dist: &Path,
) -> anyhow::Result<(ModelInfo, Option<sartor_motion::ClearanceOptions>)> {
    let name = model_dir
        .file_name()
        .and_then(|n| n.to_str())
        .with_context(|| format!("{}: not a folder name", model_dir.display()))?
        .to_string();
    let out = dist.join("models").join(&name);
    let model = GarmentModel::load(model_dir)?;
    let (mut header, mut weights) = model.into_parts();
    header.sizes.linear_baseline = false;
    weights.lr = None;
    let page_model = GarmentModel::new(header, weights)?;
    page_model.save_as(&out, TensorStorage::F16)?;
    for file in ["binding.json", "binding.safetensors"] {
        copy(&model_dir.join(file), &out.join(file))?;
    }
    let triangles = sartor_runtime::GarmentBinding::load(model_dir)?
        .faces()
        .len();
    let pipeline_path = model_dir.join("pipeline.json");
    let pipeline: serde_json::Value = serde_json::from_slice(
        &std::fs::read(&pipeline_path).with_context(|| pipeline_path.display().to_string())?,
    )
    .with_context(|| pipeline_path.display().to_string())?;
    let config_path = root.join(
        pipeline["config"]
            .as_str()
            .with_context(|| format!("{}: no \"config\"", pipeline_path.display()))?,
    );
    let config: serde_json::Value = serde_json::from_slice(
        &std::fs::read(&config_path).with_context(|| config_path.display().to_string())?,
    )
    .with_context(|| config_path.display().to_string())?;
    let arm_clearance: Option<sartor_motion::ClearanceOptions> =
        serde_json::from_value(config["simulation"]["arm_clearance"].clone())
            .with_context(|| format!("{}: simulation.arm_clearance", config_path.display()))?;
    let info = ModelInfo {
        name,
        garment: page_model.header().garment.id.clone(),
        triangles,
        storage: "f16 weight matrices, f32 vectors",
        f32_bytes: size(&model_dir.join("model.safetensors")),
        page_bytes: size(&out.join("model.safetensors")),
    };
    Ok((info, arm_clearance))
}

fn walk(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir)? {
        let path = entry?.path();
        if path.is_dir() {
            out.extend(walk(&path)?);
        } else {
            out.push(path);
        }
    }
    Ok(out)
}
