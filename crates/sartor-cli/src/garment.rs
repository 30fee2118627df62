//! `sartor garment --config configs/garments/<name>.json [--out datasets/garments/<name>]`:
//! build a garment template (procedural T-shirt or user OBJ) on the template body, relax it on
//! the body with the simulator (unless `--no-relax`), save it (`garment.safetensors`,
//! `garment.json`, `garment.obj`) and write `garment-report.json`.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Context;
use sartor_cloth::{
    GARMENT_REPORT, GarmentConfig, GarmentReport, Material, RelaxConfig, RelaxReport,
    build_garment, relax_on_body,
};
use sartor_core::io::{read_file, sha256_hex};
use sartor_core::{BodyModel, MeshProximity};
use serde::Serialize;

use sartor_eval::{Machine, write_json};
use sartor_pipeline::DataDir;

/// Arguments of `garment`.
#[derive(clap::Args, Debug)]
pub struct GarmentArgs {
    /// The garment config (a T-shirt recipe or an OBJ import).
    #[arg(long)]
    pub config: PathBuf,
    /// Output folder (default: `datasets/garments/<name>` in the data folder).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Body model folder (default: the config's `body`, else the built-in body).
    #[arg(long)]
    pub body: Option<PathBuf>,
    /// Save the garment as cut, without relaxing it on the body.
    #[arg(long)]
    pub no_relax: bool,
    /// Cloth material for the relaxation (ARCSim JSON; default: gray interlock).
    #[arg(long)]
    pub material: Option<PathBuf>,
}

#[derive(Serialize)]
struct Timings {
    load_body_s: f64,
    build_s: f64,
    relax_s: f64,
    save_s: f64,
    report_s: f64,
}

#[derive(Serialize)]
struct ReportFile<'a> {
    #[serde(flatten)]
    report: &'a GarmentReport,
    tshirt: Option<&'a sartor_cloth::TshirtStats>,
    config_path: String,
    config_sha256: String,
    body_dir: String,
    relaxed_on_body: bool,
    relaxation: Option<RelaxReport>,
    wall_time_s: f64,
    timings: Timings,
    machine: Machine,
}

/// Build, save and report one garment.
pub fn garment(args: &GarmentArgs, data: &DataDir) -> anyhow::Result<()> {
    let start = Instant::now();
    let config_bytes = read_file(&args.config)?;
    let config = GarmentConfig::from_json(&config_bytes, &args.config)?;
    let out = args
        .out
        .clone()
        .unwrap_or_else(|| data.garments_dir().join(config.name()));
    let body_dir = args
        .body
        .clone()
        .or_else(|| config.body().map(|b| data.resolve(&b)))
        .unwrap_or_else(|| data.body_dir());
    let t = Instant::now();
    let body = BodyModel::load(&body_dir)
        .with_context(|| format!("loading the body model from {}", body_dir.display()))?;
    let load_body_s = t.elapsed().as_secs_f64();

    let t = Instant::now();
    let build = build_garment(&config, &args.config, &config_bytes, &body)
        .with_context(|| format!("building the garment of {}", args.config.display()))?;
    let build_s = t.elapsed().as_secs_f64();

    let t = Instant::now();
    let (garment, relaxation) = if args.no_relax {
        (build.garment, None)
    } else {
        let material = match &args.material {
            Some(path) => Material::from_json_file(path)?,
            None => Material::gray_interlock(),
        };
        let (garment, report) =
            relax_on_body(&build.garment, &body, &material, &RelaxConfig::default())
                .with_context(|| format!("relaxing {} on the body", config.name()))?;
        (garment, Some(report))
    };
    let relax_s = t.elapsed().as_secs_f64();

    let t = Instant::now();
    garment
        .save(&out)
        .with_context(|| format!("saving the garment into {}", out.display()))?;
    let save_s = t.elapsed().as_secs_f64();

    let t = Instant::now();
    let proximity = MeshProximity::new(body.template().positions(), body.faces())?;
    let report = GarmentReport::measure(&garment, Some(&proximity));
    let report_s = t.elapsed().as_secs_f64();
    let file = ReportFile {
        report: &report,
        tshirt: build.tshirt.as_ref(),
        config_path: args.config.display().to_string(),
        config_sha256: sha256_hex(&config_bytes),
        body_dir: data.relative(&body_dir),
        relaxed_on_body: relaxation.is_some(),
        relaxation: relaxation.clone(),
        wall_time_s: start.elapsed().as_secs_f64(),
        timings: Timings {
            load_body_s,
            build_s,
            relax_s,
            save_s,
            report_s,
        },
        machine: Machine::current(),
    };
    write_json(&out.join(GARMENT_REPORT), &file)?;

    let m = &report.mesh;
    println!(
        "wrote {}: {} triangles, {} vertices, {:.3} m², {} boundary loops, min angle {:.1}°, \
         edges p5/p50/p95 {:.1}/{:.1}/{:.1} mm",
        out.display(),
        m.triangles,
        m.vertices,
        m.area_m2,
        m.boundary_loops,
        m.min_angle_deg,
        m.edge_length.p5_mm,
        m.edge_length.p50_mm,
        m.edge_length.p95_mm
    );
    if let Some(r) = &relaxation {
        println!(
            "relaxed on the body in {} frames ({relax_s:.1} s): largest speed {:.2} mm/s, \
             closest to the body {:.1} mm, moved {:.1} mm on average",
            r.frames,
            r.max_speed_m_per_s * 1e3,
            r.min_signed_distance_mm,
            r.mean_displacement_mm
        );
    }
    if let Some(fit) = &report.body {
        println!(
            "ease min/mean/max {:.1}/{:.1}/{:.1} mm, {} vertices inside the body; built in {build_s:.2} s",
            fit.ease_min_mm, fit.ease_mean_mm, fit.ease_max_mm, fit.vertices_inside
        );
    }
    Ok(())
}
