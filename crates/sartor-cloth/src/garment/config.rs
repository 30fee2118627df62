//! Garment configs (`configs/garments/*.json`): a procedural T-shirt recipe or a user OBJ,
//! and the one function that turns a config into a [`Garment`].

use std::path::{Path, PathBuf};

use sartor_core::BodyModel;
use sartor_core::io::sha256_hex;
use serde::{Deserialize, Serialize};

use super::frame::material_u_axes;
use super::import::{ObjImportOptions, import_obj_garment};
use super::template::{Garment, GarmentProvenance, SourceKind};
use super::tshirt::{TshirtRecipe, TshirtStats, build_tshirt};
use crate::{Error, Result};

/// A user garment given as an OBJ positioned on the template body.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjGarmentConfig {
    /// The garment's name (its folder under `datasets/garments/`).
    pub name: String,
    /// The OBJ file, relative to the working directory (the workspace root for
    /// `cargo xtask`).
    pub obj: String,
    /// Folder of the body model, relative to the working directory; `None` for the built-in
    /// body.
    #[serde(default)]
    pub body: Option<String>,
    /// Use the OBJ's `vt` as a flat sewing pattern with this many metres per texture unit;
    /// `None` (or absent) makes the 3D positions the rest shape.
    #[serde(default)]
    pub pattern_scale_m: Option<f64>,
}

/// A garment config: a procedural T-shirt recipe, or a user OBJ (recognised by its `obj`
/// field).
#[derive(Clone, Debug, PartialEq)]
pub enum GarmentConfig {
    /// A procedural T-shirt.
    Tshirt(TshirtRecipe),
    /// A user OBJ.
    Obj(ObjGarmentConfig),
}

impl GarmentConfig {
    /// Parse and validate a config from JSON; `path` names the file in errors.
    pub fn from_json(bytes: &[u8], path: &Path) -> Result<Self> {
        let value: serde_json::Value = serde_json::from_slice(bytes)
            .map_err(|e| Error::format(path, format!("line {}: {e}", e.line())))?;
        if value.get("obj").is_some() {
            let config: ObjGarmentConfig =
                serde_json::from_value(value).map_err(|e| Error::format(path, e.to_string()))?;
            if config.name.is_empty() || config.name.contains(['/', '\\']) {
                return Err(Error::format(
                    path,
                    format!("name {:?} must be non-empty, without slashes", config.name),
                ));
            }
            Ok(Self::Obj(config))
        } else {
            Ok(Self::Tshirt(TshirtRecipe::from_json(bytes, path)?))
        }
    }

    /// Read and validate a config file.
    pub fn load(path: &Path) -> Result<Self> {
        Self::from_json(&sartor_core::io::read_file(path)?, path)
    }

    /// The garment's name.
    pub fn name(&self) -> &str {
        match self {
            Self::Tshirt(r) => &r.name,
            Self::Obj(c) => &c.name,
        }
    }

    /// The body folder the config names, if any (`None`: the built-in body).
    pub fn body(&self) -> Option<PathBuf> {
        match self {
            Self::Tshirt(r) => r.body.as_ref(),
            Self::Obj(c) => c.body.as_ref(),
        }
        .map(PathBuf::from)
    }
}

/// A garment made from a config, with what was measured on the way.
#[derive(Clone, Debug)]
pub struct GarmentBuild {
    /// The garment.
    pub garment: Garment,
    /// Figures of the T-shirt construction (procedural garments only).
    pub tshirt: Option<TshirtStats>,
}

/// Make the garment of `config` on `body`. `config_path` and `config_bytes` are the config
/// file and its bytes (their hash goes into the provenance, with the body's identity).
pub fn build_garment(
    config: &GarmentConfig,
    config_path: &Path,
    config_bytes: &[u8],
    body: &BodyModel,
) -> Result<GarmentBuild> {
    match config {
        GarmentConfig::Tshirt(recipe) => {
            let surface = build_tshirt(body, recipe)?;
            let axes = material_u_axes(&surface.mesh, Some(body))?;
            let provenance = GarmentProvenance {
                kind: SourceKind::Recipe,
                path: config_path.display().to_string(),
                sha256: sha256_hex(config_bytes),
                body: Some(body.asset_id()?),
            };
            Ok(GarmentBuild {
                garment: Garment::from_surface(&recipe.name, &surface.mesh, &axes, provenance)?,
                tshirt: Some(surface.stats),
            })
        }
        GarmentConfig::Obj(c) => {
            let options = ObjImportOptions {
                name: c.name.clone(),
                pattern_scale_m: c.pattern_scale_m,
            };
            Ok(GarmentBuild {
                garment: import_obj_garment(Path::new(&c.obj), &options, Some(body))?,
                tshirt: None,
            })
        }
    }
}
