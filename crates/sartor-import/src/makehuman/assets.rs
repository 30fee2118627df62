//! Readers for the raw MakeHuman assets (only the importer uses them): the base mesh, vertex
//! groups, gzipped targets, `macro.json`, the `cmu_mb` rig, its weights and the T-pose. Every
//! error names the file and, for text files, the line.

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use serde::Deserialize;
use serde::de::DeserializeOwned;

use crate::{Error, Result};
use sartor_core::io::read_file;
use sartor_core::{MacroPart, MacroTarget, MacroVariable, ObjData};

/// The base mesh's polygons of one group plus all positions, in the file's units (dm).
pub(crate) struct BaseMesh {
    pub positions_dm: Vec<Vector3<f64>>,
    /// Polygons (vertex indices, 0-based) of the requested group, in file order.
    pub polygons: Vec<Vec<u32>>,
}

/// Read `base.obj` (sartor-core's OBJ reader): every vertex and the polygons of `group`.
pub(crate) fn read_base_obj(path: &Path, group: &str) -> Result<BaseMesh> {
    let data = ObjData::read(path)?;
    Ok(BaseMesh {
        polygons: data.group_polygons(group, path)?,
        positions_dm: data.positions,
    })
}

fn read_json<T: DeserializeOwned>(path: &Path) -> Result<T> {
    serde_json::from_slice(&read_file(path)?)
        .map_err(|e| Error::parse(path, e.line(), e.to_string()))
}

/// `basemesh_vertex_groups.json`: group name → inclusive index ranges, as vertex lists.
pub(crate) fn read_vertex_groups(path: &Path) -> Result<BTreeMap<String, Vec<u32>>> {
    let raw: BTreeMap<String, Vec<[u32; 2]>> = read_json(path)?;
    raw.into_iter()
        .map(|(name, ranges)| {
            let mut v = Vec::new();
            for [a, b] in ranges {
                if b < a {
                    return Err(Error::format(
                        path,
                        format!("group {name:?}: range [{a}, {b}] is reversed"),
                    ));
                }
                v.extend(a..=b);
            }
            Ok((name, v))
        })
        .collect()
}

/// A target: sparse displacements in decimetres, sorted by vertex.
pub(crate) struct Target {
    /// `(vertex, [dx, dy, dz] dm)`.
    pub entries: Vec<(u32, [f32; 3])>,
}

/// Read a gzipped `index dx dy dz` target (decimetres). Vertex indices must be below
/// `n_vertices`; lines starting with `#` and blank lines are skipped; entries are sorted by
/// vertex and a repeated vertex is an error.
pub(crate) fn read_target(path: &Path, n_vertices: usize) -> Result<Target> {
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let reader = BufReader::new(flate2::read::GzDecoder::new(file));
    let mut entries = Vec::new();
    for (i, line) in reader.lines().enumerate() {
        let line = line.map_err(|e| Error::io(path, e))?;
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let err = |m: String| Error::parse(path, i + 1, m);
        let mut f = line.split_whitespace();
        let idx = f
            .next()
            .and_then(|s| s.parse::<u32>().ok())
            .filter(|&k| (k as usize) < n_vertices)
            .ok_or_else(|| err(format!("bad vertex index (mesh has {n_vertices})")))?;
        let mut d = [0.0f32; 3];
        for x in &mut d {
            let s = f.next().ok_or_else(|| err("missing coordinate".into()))?;
            *x = s
                .parse::<f32>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| err(format!("{s:?} is not a finite number")))?;
        }
        if f.next().is_some() {
            return Err(err("more than four fields".into()));
        }
        entries.push((idx, d));
    }
    entries.sort_by_key(|e| e.0);
    if let Some(w) = entries.windows(2).find(|w| w[0].0 == w[1].0) {
        return Err(Error::format(
            path,
            format!("vertex {} is listed twice", w[0].0),
        ));
    }
    Ok(Target { entries })
}

#[derive(Deserialize)]
struct RawMacroFile {
    macrotargets: BTreeMap<String, RawMacroVariable>,
    combinations: BTreeMap<String, Vec<String>>,
}

#[derive(Deserialize)]
struct RawMacroVariable {
    parts: Vec<RawMacroPart>,
}

#[derive(Deserialize)]
struct RawMacroPart {
    lowest: f64,
    highest: f64,
    low: String,
    high: String,
}

/// `macro.json` turned into slider variables and the list of label combinations.
pub(crate) struct MacroFile {
    pub variables: Vec<MacroVariable>,
    /// Combination name → variable names (`race` or slider names), in file-name order.
    pub combinations: BTreeMap<String, Vec<String>>,
}

/// Our slider name for a `macro.json` variable.
fn slider_name(macro_name: &str) -> &str {
    match macro_name {
        "cupsize" => "cup_size",
        other => other,
    }
}

/// Read `macro.json`. Its parts are padded with small gaps (`0.1874998` / `0.1874999`,
/// `0.49` / `0.51`, `-0.01` / `1.01`); the nominal boundaries are MakeHuman's breakpoints
/// (0.1875 and 0.5, `apps/human.py`), so each inner boundary is snapped to the nearest 1/16
/// and must lie within 0.011 of both padded ends; the outer ones are 0 and 1.
pub(crate) fn read_macro_json(path: &Path) -> Result<MacroFile> {
    let raw: RawMacroFile = read_json(path)?;
    let mut variables = Vec::new();
    for (name, var) in &raw.macrotargets {
        let bad = |m: String| Error::format(path, format!("macrotargets.{name}: {m}"));
        let n = var.parts.len();
        if n == 0 {
            return Err(bad("no parts".into()));
        }
        let mut bounds = vec![0.0];
        for w in var.parts.windows(2) {
            let mid = 0.5 * (w[0].highest + w[1].lowest);
            let snapped = (mid * 16.0).round() / 16.0;
            if (snapped - w[0].highest).abs() > 0.011 || (snapped - w[1].lowest).abs() > 0.011 {
                return Err(bad(format!(
                    "parts end at {} and start at {}: not a breakpoint",
                    w[0].highest, w[1].lowest
                )));
            }
            bounds.push(snapped);
        }
        bounds.push(1.0);
        if var.parts[0].lowest > 0.0 || var.parts[n - 1].highest < 1.0 {
            return Err(bad("parts do not cover [0, 1]".into()));
        }
        let label = |s: &str| (!s.is_empty()).then(|| s.to_string());
        let parts = var
            .parts
            .iter()
            .enumerate()
            .map(|(i, p)| MacroPart {
                from: bounds[i],
                to: bounds[i + 1],
                low: label(&p.low),
                high: label(&p.high),
            })
            .collect();
        variables.push(MacroVariable {
            name: slider_name(name).to_string(),
            parts,
        });
    }
    // Slider order, not the file's alphabetical order.
    variables.sort_by_key(|v| {
        sartor_core::SLIDERS
            .iter()
            .position(|s| *s == v.name)
            .unwrap_or(usize::MAX)
    });
    let combinations = raw
        .combinations
        .into_iter()
        .map(|(k, vars)| {
            let vars = vars.iter().map(|v| slider_name(v).to_string()).collect();
            (k, vars)
        })
        .collect();
    Ok(MacroFile {
        variables,
        combinations,
    })
}

/// The races of MakeHuman's `racegenderage` targets. `macro.json` gives no race weights, so
/// the importer blends them equally (MakeHuman's default: 1/3 each).
pub(crate) const RACES: [&str; 3] = ["african", "asian", "caucasian"];

/// Parse a macro target's file stem (`universal-female-young-averagemuscle-maxweight`,
/// `african-male-old`, `female-young-minmuscle-averageweight-maxcup-minfirmness`, ...) into
/// its labels, if it is one: every label known and the sequence of their variables one of the
/// `combinations` of `macro.json`. A leading `universal` (MakeHuman's prefix of the
/// gender-age-muscle-weight targets) is dropped.
pub(crate) fn parse_macro_target_name(stem: &str, macro_file: &MacroFile) -> Option<Vec<String>> {
    let mut tokens: Vec<&str> = stem.split('-').collect();
    if tokens.first() == Some(&"universal") {
        tokens.remove(0);
    }
    let var_of = |label: &str| -> Option<&str> {
        if RACES.contains(&label) {
            return Some("race");
        }
        macro_file.variables.iter().find_map(|v| {
            v.parts
                .iter()
                .any(|p| p.low.as_deref() == Some(label) || p.high.as_deref() == Some(label))
                .then_some(v.name.as_str())
        })
    };
    let vars: Option<Vec<&str>> = tokens.iter().map(|t| var_of(t)).collect();
    let vars = vars?;
    macro_file
        .combinations
        .values()
        .any(|c| c.iter().map(String::as_str).eq(vars.iter().copied()))
        .then(|| tokens.iter().map(|t| t.to_string()).collect())
}

/// The macro targets found under `targets_dir`: every `*.target.gz` in `macrodetails/`,
/// `macrodetails/height/` and `macrodetails/proportions/` (each must be a macro target), and
/// those of `breast/` that are (cup size / firmness); the other `breast/` targets are local
/// modifiers and are skipped. Sorted by name.
pub(crate) fn list_macro_targets(
    targets_dir: &Path,
    macro_file: &MacroFile,
) -> Result<(Vec<MacroTarget>, Vec<PathBuf>, usize)> {
    let mut found = Vec::new();
    let mut skipped = 0;
    for (sub, required) in [
        ("macrodetails", true),
        ("macrodetails/height", true),
        ("macrodetails/proportions", true),
        ("breast", false),
    ] {
        let dir = targets_dir.join(sub);
        let mut names = Vec::new();
        for entry in std::fs::read_dir(&dir).map_err(|e| Error::io(&dir, e))? {
            let entry = entry.map_err(|e| Error::io(&dir, e))?;
            let file_name = entry.file_name().to_string_lossy().into_owned();
            if let Some(stem) = file_name.strip_suffix(".target.gz") {
                names.push(stem.to_string());
            }
        }
        names.sort();
        for stem in names {
            match parse_macro_target_name(&stem, macro_file) {
                Some(labels) => found.push((
                    MacroTarget {
                        name: format!("{sub}/{stem}"),
                        labels,
                    },
                    dir.join(format!("{stem}.target.gz")),
                )),
                None if required => {
                    return Err(Error::format(
                        dir.join(format!("{stem}.target.gz")),
                        "not a macro target: its labels match no combination of macro.json",
                    ));
                }
                None => skipped += 1,
            }
        }
    }
    found.sort_by(|a, b| a.0.name.cmp(&b.0.name));
    let (targets, paths) = found.into_iter().unzip();
    Ok((targets, paths, skipped))
}

#[derive(Deserialize)]
struct RawWeights {
    weights: BTreeMap<String, Vec<(u32, f64)>>,
}

/// Read `weights.*.json`: bone → `(vertex, weight)` list.
pub(crate) fn read_weights(path: &Path) -> Result<BTreeMap<String, Vec<(u32, f64)>>> {
    let raw: RawWeights = read_json(path)?;
    Ok(raw.weights)
}

#[derive(Deserialize)]
struct RawPose {
    bone_rotations: BTreeMap<String, [f64; 3]>,
    bone_translations: BTreeMap<String, serde_json::Value>,
    skeleton_type: String,
}

/// Read an MPFB pose (`poses/cmu_mb_fk/*.json`): bone → Euler XYZ rotation (radians, Blender
/// pose-bone local frame). Translations are not supported (the T-pose has none).
pub(crate) fn read_pose(path: &Path) -> Result<BTreeMap<String, [f64; 3]>> {
    let raw: RawPose = read_json(path)?;
    if raw.skeleton_type != "cmu_mb" {
        return Err(Error::format(
            path,
            format!("skeleton_type {:?}, expected \"cmu_mb\"", raw.skeleton_type),
        ));
    }
    if !raw.bone_translations.is_empty() {
        return Err(Error::format(path, "bone translations are not supported"));
    }
    if let Some((b, r)) = raw
        .bone_rotations
        .iter()
        .find(|(_, r)| r.iter().any(|x| !x.is_finite()))
    {
        return Err(Error::format(
            path,
            format!("bone {b}: rotation {r:?} is not finite"),
        ));
    }
    Ok(raw.bone_rotations)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn macro_file() -> MacroFile {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("macro.json");
        std::fs::write(
            &path,
            r#"{"macrotargets": {
                "gender": {"label": "Gender", "parts": [{"lowest": -0.01, "highest": 1.01, "low": "female", "high": "male"}]},
                "age": {"parts": [
                    {"lowest": -0.01, "highest": 0.1874998, "low": "baby", "high": "child"},
                    {"lowest": 0.1874999, "highest": 0.49998, "low": "child", "high": "young"},
                    {"lowest": 0.49999, "highest": 1.01, "low": "young", "high": "old"}]},
                "height": {"parts": [
                    {"lowest": -0.01, "highest": 0.49, "low": "minheight", "high": ""},
                    {"lowest": 0.51, "highest": 1.01, "low": "", "high": "maxheight"}]}
              },
              "combinations": {"racegenderage": ["race", "gender", "age"],
                               "gah": ["gender", "age", "height"]}}"#,
        )
        .expect("write");
        read_macro_json(&path).expect("valid")
    }

    #[test]
    fn macro_json_breakpoints_are_snapped() {
        let m = macro_file();
        let names: Vec<&str> = m.variables.iter().map(|v| v.name.as_str()).collect();
        assert_eq!(names, ["gender", "age", "height"]);
        let age = &m.variables[1];
        let b: Vec<(f64, f64)> = age.parts.iter().map(|p| (p.from, p.to)).collect();
        assert_eq!(b, [(0.0, 0.1875), (0.1875, 0.5), (0.5, 1.0)]);
        assert_eq!(m.variables[2].parts[0].high, None);
    }

    #[test]
    fn target_names_parse_by_combination() {
        let m = macro_file();
        assert_eq!(
            parse_macro_target_name("asian-male-old", &m),
            Some(vec!["asian".into(), "male".into(), "old".into()])
        );
        assert!(parse_macro_target_name("female-young-maxheight", &m).is_some());
        // Wrong order, unknown label, local target.
        assert!(parse_macro_target_name("young-female-maxheight", &m).is_none());
        assert!(parse_macro_target_name("female-young-hugeheight", &m).is_none());
        assert!(parse_macro_target_name("breast-dist-decr", &m).is_none());
    }

    #[test]
    fn targets_are_checked() {
        let dir = tempfile::tempdir().expect("tempdir");
        let write = |name: &str, text: &str| {
            let path = dir.path().join(name);
            let mut gz = flate2::write::GzEncoder::new(
                std::fs::File::create(&path).expect("create"),
                flate2::Compression::default(),
            );
            gz.write_all(text.as_bytes()).expect("write");
            gz.finish().expect("finish");
            path
        };
        let ok = write("ok.target.gz", "# comment\n2 .5 -.25 0\n0 1 2 3\n");
        let t = read_target(&ok, 3).expect("valid");
        assert_eq!(
            t.entries,
            vec![(0, [1.0, 2.0, 3.0]), (2, [0.5, -0.25, 0.0])]
        );
        for (name, text, want) in [
            ("range.target.gz", "3 0 0 0\n", ":1: bad vertex index"),
            (
                "nan.target.gz",
                "0 0 nan 0\n",
                ":1: \"nan\" is not a finite",
            ),
            ("short.target.gz", "0 0 0\n", "missing coordinate"),
            ("dup.target.gz", "0 0 0 0\n0 1 1 1\n", "listed twice"),
        ] {
            let path = write(name, text);
            let err = read_target(&path, 3).err().expect("must fail").to_string();
            assert!(err.contains(name) && err.contains(want), "{err}");
        }
    }
}
