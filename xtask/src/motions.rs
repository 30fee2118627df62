//! `cargo xtask import-motion`: convert MakeHuman's keyframed walk cycle into
//! `datasets/motions/walk.json` (a 30 fps [`sartor_motion::Motion`] on the built-in skeleton).
//! `cargo xtask import-motions`: import the CMU BVH clips into `datasets/motions/cmu/` as
//! stored clips ([`sartor_motion::StoredClip`]).

use std::path::PathBuf;

use anyhow::Context;

/// Arguments of `import-motion`.
#[derive(clap::Args, Debug)]
pub struct ImportMotionArgs {
    /// The MakeHuman assets folder (holding `walkcycles/` and `rigs/`).
    #[arg(long, default_value = "../shared/makehuman")]
    pub from: PathBuf,
    /// Output folder; the motion is written to `<out>/walk.json`.
    #[arg(long, default_value = "datasets/motions")]
    pub out: PathBuf,
}

/// Import the walk cycle and write it.
pub fn import_motion(args: &ImportMotionArgs) -> anyhow::Result<()> {
    let motion = sartor_import::import_walk_cycle(&args.from)
        .with_context(|| format!("importing the walk cycle from {}", args.from.display()))?;
    let path = args.out.join(format!("{}.json", sartor_motion::WALK_NAME));
    motion.save_json(&path)?;
    let last = &motion.frames()[motion.n_frames() - 1];
    println!(
        "wrote {}: {} frames at {} fps ({:.2} s), root travels {:.2} m forward",
        path.display(),
        motion.n_frames(),
        motion.fps(),
        motion.duration_secs(),
        last.root_translation_m.z - motion.frames()[0].root_translation_m.z,
    );
    Ok(())
}

/// Arguments of `import-motions`.
#[derive(clap::Args, Debug)]
pub struct ImportMotionsArgs {
    /// A folder of CMU BVH clips with a `SHA256SUMS` file (the CMU conversion's clips).
    #[arg(long, default_value = "../shared/cmu")]
    pub from: PathBuf,
    /// The motions folder; the clips are written to `<out>/<set>/`.
    #[arg(long, default_value = "datasets/motions")]
    pub out: PathBuf,
    /// The set's name (clips are named `<set>/<file stem>`).
    #[arg(long, default_value = "cmu")]
    pub set: String,
}

/// One imported clip, for the provenance table.
struct Imported {
    header: sartor_motion::StoredClipHeader,
    bytes: usize,
    max_error: f64,
}

/// Import every `.bvh` of `--from` (checked against its `SHA256SUMS`) as stored clips
/// (`sartor_motion::StoredClip`) into `<out>/<set>/`, with a README (acknowledgement, command)
/// and a PROVENANCE table. Deterministic: a re-run writes the same bytes.
pub fn import_motions(args: &ImportMotionsArgs) -> anyhow::Result<()> {
    let sums_path = args.from.join("SHA256SUMS");
    let sums = std::fs::read_to_string(&sums_path)
        .with_context(|| format!("reading {}", sums_path.display()))?;
    let sums: std::collections::BTreeMap<String, String> = sums
        .lines()
        .filter_map(|l| {
            let (hash, file) = l.split_once(char::is_whitespace)?;
            Some((
                file.trim().trim_start_matches('*').to_string(),
                hash.to_string(),
            ))
        })
        .collect();
    let mut files: Vec<PathBuf> = std::fs::read_dir(&args.from)
        .with_context(|| format!("reading {}", args.from.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "bvh"))
        .collect();
    files.sort();
    anyhow::ensure!(
        !files.is_empty(),
        "no .bvh files in {}",
        args.from.display()
    );
    let dir = args.out.join(&args.set);
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut imported = Vec::with_capacity(files.len());
    for path in &files {
        let file = path
            .file_name()
            .map(|f| f.to_string_lossy().into_owned())
            .unwrap_or_default();
        let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
        let hash = sartor_core::io::sha256_hex(&bytes);
        let listed = sums
            .get(&file)
            .with_context(|| format!("{file} is not listed in {}", sums_path.display()))?;
        anyhow::ensure!(
            *listed == hash,
            "{}: SHA-256 {hash} differs from {listed} in {}",
            path.display(),
            sums_path.display()
        );
        let text = String::from_utf8(bytes).with_context(|| format!("{file}: not UTF-8"))?;
        let bvh = sartor_motion::Bvh::parse(&text, path)?;
        let stem = path
            .file_stem()
            .map(|f| f.to_string_lossy().into_owned())
            .unwrap_or_default();
        let name = format!("{}/{stem}", args.set);
        let clip = sartor_motion::StoredClip::from_bvh(
            &bvh,
            &name,
            &hash,
            sartor_motion::CMU_ACKNOWLEDGEMENT,
        )?;
        clip.save(&dir)?;
        // Fidelity of the stored f32 values against the file's.
        let h = &clip.header;
        let c = bvh.n_channels();
        let k = h.stored_channels.len();
        let mut max_error: f64 = 0.0;
        for (row, i) in (h.first_source_frame..bvh.n_frames())
            .step_by(h.source_frame_step)
            .enumerate()
        {
            for ch in 0..c {
                let stored = h
                    .stored_channels
                    .iter()
                    .position(|&s| s == ch)
                    .map_or(0.0, |col| f64::from(clip.values[row * k + col]));
                max_error = max_error.max((stored - bvh.values()[i * c + ch]).abs());
            }
        }
        let (json, st) = clip.to_bytes()?;
        imported.push(Imported {
            header: clip.header,
            bytes: json.len() + st.len(),
            max_error,
        });
    }
    write_readme(&dir, args, &imported)?;
    let total: usize = imported.iter().map(|c| c.bytes).sum();
    let frames: usize = imported.iter().map(|c| c.header.frames).sum();
    let worst = imported.iter().map(|c| c.max_error).fold(0.0, f64::max);
    println!(
        "wrote {} clips ({frames} frames at 30 fps, {:.2} MB) to {}; T-pose frame dropped in {}; \
         largest difference of a stored value from the file's: {worst:.2e}",
        imported.len(),
        total as f64 / 1e6,
        dir.display(),
        imported
            .iter()
            .filter(|c| c.header.tpose_frame_dropped)
            .count(),
    );
    Ok(())
}

/// `README.md` (what the set is, the acknowledgement, the command) and `PROVENANCE.md` (per clip:
/// source hash, frames, what was changed) in `dir`.
fn write_readme(
    dir: &std::path::Path,
    args: &ImportMotionsArgs,
    clips: &[Imported],
) -> anyhow::Result<()> {
    let set = &args.set;
    let readme = format!(
        "# `{set}/`: CMU motion capture, imported\n\n\
         {n} clips of the CMU Graphics Lab Motion Capture Database (mocap.cs.cmu.edu), in the\n\
         \"MotionBuilder-friendly\" BVH conversion by B. Hahne (cgspeed, 2010 release), stored as\n\
         each file's own skeleton and channel values (`<clip>.json` + `<clip>.safetensors`, see\n\
         `sartor_motion::StoredClip`); `sartor_motion::load_motion` retargets them onto the body at\n\
         load. Names: `{set}/<clip>`; the set `{set}/*` is every clip in name order.\n\n\
         **Acknowledgement (asked for by CMU wherever the data or data derived from it is\n\
         shipped):** \"{ack}\"\n\n\
         CMU's terms: the data is free for research and commercial use and may be included in\n\
         products; it may not be resold as data, even converted. The conversion adds no further\n\
         restrictions.\n\n\
         Made by `cargo xtask import-motions --from <the 60 clips> --set {set}` (default\n\
         `--from ../shared/cmu`); a re-run writes the same bytes. What was changed, per clip:\n\
         `PROVENANCE.md`.\n",
        n = clips.len(),
        ack = sartor_motion::CMU_ACKNOWLEDGEMENT,
    );
    let mut prov = format!(
        "# Provenance of `{set}/`\n\n\
         Source: the files of `--from` (checked against its `SHA256SUMS`). For every clip: the\n\
         hierarchy is kept unchanged; frame 0 is dropped when it is the T-pose the conversion\n\
         adds (`sartor_motion::detect_tpose_frame`: a T-pose that jumps to frame 1); of the rest,\n\
         every 4th frame is kept (120 fps → 30 fps, the frames resampling to 30 fps lands on);\n\
         the values are stored as f32 (largest difference from the file's text: the last\n\
         column); channels that are zero in every kept frame are not stored (they read back as\n\
         zero).\n\n\
         | clip | source sha256 | source frames | T-pose frame dropped | source frames kept | frames at 30 fps | channels stored | largest f32 difference |\n\
         | --- | --- | --- | --- | --- | --- | --- | --- |\n"
    );
    for c in clips {
        let h = &c.header;
        let last = h.first_source_frame + (h.frames - 1) * h.source_frame_step;
        prov.push_str(&format!(
            "| `{}` | `{}` | {} | {} | {}, {}, …, {last} | {} | {} of {} | {:.1e} |\n",
            h.name,
            h.source.sha256,
            h.source.frames,
            if h.tpose_frame_dropped { "yes" } else { "no" },
            h.first_source_frame,
            h.first_source_frame + h.source_frame_step,
            h.frames,
            h.stored_channels.len(),
            h.joints.iter().map(|j| j.channels.len()).sum::<usize>(),
            c.max_error,
        ));
    }
    sartor_core::io::write_atomic(&dir.join("README.md"), readme.as_bytes())?;
    sartor_core::io::write_atomic(&dir.join("PROVENANCE.md"), prov.as_bytes())?;
    Ok(())
}
