//! The one asset-file convention of sartor: a JSON header beside a safetensors file, the header
//! naming its `format` and `version` and carrying the tensors' SHA-256 (`tensors_sha256`).
//!
//! Body models, phenotype spaces, garment templates, garment bindings and exported networks
//! all use it. [`AssetFiles`] writes the pair (tensors first, header last, each atomically, so
//! a reader that finds the header finds the tensors it describes) and reads it back, checking
//! the JSON, the format and version, the hash's form and the hash itself before any tensor is
//! trusted. What each asset checks beyond that (shapes, invariants) stays with the asset.

use std::path::Path;

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::io::{TensorFile, read_file, sha256_hex, write_atomic};
use crate::{Error, Result};

/// A header of an asset file pair: its format name, version and the tensors' hash.
pub trait AssetHeader: Serialize + DeserializeOwned {
    /// The `format` field.
    fn format(&self) -> &str;
    /// The `version` field.
    fn version(&self) -> u32;
    /// The `tensors_sha256` field.
    fn tensors_sha256(&self) -> &str;
    /// The `units` field of a header that has one; [`AssetFiles::parse`] refuses any but `"m"`.
    fn units(&self) -> Option<&str> {
        None
    }
}

/// Implement [`AssetHeader`] for a header struct with `format: String`, `version: u32` and
/// `tensors_sha256: String` fields; `asset_header!(H, units)` also for its `units: String`.
#[macro_export]
macro_rules! asset_header {
    ($header:ty, units) => {
        $crate::asset_header!($header, fn units(&self) -> Option<&str> { Some(&self.units) });
    };
    ($header:ty $(, $extra:item)?) => {
        impl $crate::asset::AssetHeader for $header {
            fn format(&self) -> &str {
                &self.format
            }
            fn version(&self) -> u32 {
                self.version
            }
            fn tensors_sha256(&self) -> &str {
                &self.tensors_sha256
            }
            $($extra)?
        }
    };
}

/// The one identity of an asset (a body model, a garment): its name and the SHA-256 of its
/// tensor file, the `tensors_sha256` its header records. Simulations, datasets, exported
/// models and bindings all name their garment and body this way, so a runtime can refuse a
/// mismatched pair.
#[derive(Clone, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AssetId {
    /// Name, e.g. `tshirt-4210` or `makehuman-cmu_mb`.
    pub id: String,
    /// Lower-case hex SHA-256 of the asset's tensor file.
    pub sha256: String,
}

impl AssetId {
    /// Check that the name is not empty and the hash is 64 lower-case hex digits; the message
    /// names `field`.
    pub fn check(&self, field: &str) -> std::result::Result<(), String> {
        if self.id.is_empty() {
            return Err(format!("{field}.id is empty"));
        }
        if !is_sha256(&self.sha256) {
            return Err(format!("{field}.sha256 is not 64 lower-case hex digits"));
        }
        Ok(())
    }
}

/// Whether `s` is a SHA-256 as sartor writes it: 64 lower-case hex digits.
pub fn is_sha256(s: &str) -> bool {
    s.len() == 64
        && s.bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

/// The two files of an asset kind inside a folder, and the format and version it reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AssetFiles {
    /// File name of the JSON header, e.g. `model.json`.
    pub header: &'static str,
    /// File name of the tensors, e.g. `model.safetensors`.
    pub tensors: &'static str,
    /// The header's `format`.
    pub format: &'static str,
    /// The one `version` this build reads and writes.
    pub version: u32,
}

impl AssetFiles {
    /// The header's JSON as written: pretty, with a trailing newline (deterministic).
    pub fn header_json<H: Serialize>(&self, dir: &Path, header: &H) -> Result<Vec<u8>> {
        let mut json = serde_json::to_string_pretty(header)
            .map_err(|e| Error::format(dir.join(self.header), format!("header: {e}")))?;
        json.push('\n');
        Ok(json.into_bytes())
    }

    /// Write `tensor_bytes` and then `header` into `dir`, each atomically. The header's
    /// `tensors_sha256` must be the hash of `tensor_bytes` (see [`sha256_hex`]).
    pub fn write<H: AssetHeader>(&self, dir: &Path, header: &H, tensor_bytes: &[u8]) -> Result<()> {
        if header.tensors_sha256() != sha256_hex(tensor_bytes) {
            return Err(Error::invalid(
                "asset",
                format!("{}: tensors_sha256 is not the tensors' hash", self.header),
            ));
        }
        let json = self.header_json(dir, header)?;
        write_atomic(&dir.join(self.tensors), tensor_bytes)?;
        write_atomic(&dir.join(self.header), &json)
    }

    /// Read the pair from `dir` and check it (see [`Self::parse`]).
    pub fn read<H: AssetHeader>(&self, dir: &Path) -> Result<(H, TensorFile)> {
        let (header, tensors) = self.read_bytes(dir)?;
        self.parse(dir, &header, tensors)
    }

    /// The bytes of the header and of the tensors in `dir`, unchecked (for a `from_bytes`
    /// constructor, which also serves bytes that did not come from files).
    pub fn read_bytes(&self, dir: &Path) -> Result<(Vec<u8>, Vec<u8>)> {
        Ok((
            read_file(&dir.join(self.header))?,
            read_file(&dir.join(self.tensors))?,
        ))
    }

    /// Parse the pair from bytes read from folder `dir` (named in errors only): the header's
    /// JSON, its format and version, the form of its hash, and that the tensors hash to it.
    pub fn parse<H: AssetHeader>(
        &self,
        dir: &Path,
        header_bytes: &[u8],
        tensor_bytes: Vec<u8>,
    ) -> Result<(H, TensorFile)> {
        let header_path = dir.join(self.header);
        let header: H = serde_json::from_slice(header_bytes)
            .map_err(|e| Error::parse(&header_path, e.line(), e.to_string()))?;
        if header.format() != self.format || header.version() != self.version {
            return Err(Error::format(
                &header_path,
                format!(
                    "format {:?} version {} is not {:?} version {}",
                    header.format(),
                    header.version(),
                    self.format,
                    self.version
                ),
            ));
        }
        if !is_sha256(header.tensors_sha256()) {
            return Err(Error::format(
                &header_path,
                "tensors_sha256 is not 64 lower-case hex digits",
            ));
        }
        if let Some(units) = header.units().filter(|u| *u != "m") {
            return Err(Error::format(
                &header_path,
                format!("units {units:?}, expected \"m\""),
            ));
        }
        let tensor_path = dir.join(self.tensors);
        let hash = sha256_hex(&tensor_bytes);
        if hash != header.tensors_sha256() {
            return Err(Error::format(
                &tensor_path,
                format!(
                    "content hash (SHA-256 {hash}) does not match tensors_sha256 {} in {}",
                    header.tensors_sha256(),
                    header_path.display()
                ),
            ));
        }
        Ok((header, TensorFile::from_bytes(&tensor_path, tensor_bytes)?))
    }
}
