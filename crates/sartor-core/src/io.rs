//! File helpers shared across sartor: atomic writes and checked safetensors access.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use nalgebra::Vector3;
use safetensors::{Dtype, SafeTensors, tensor::TensorView};
use sha2::{Digest, Sha256};

use crate::{Error, Result};

/// Write `bytes` to `path` atomically: a temporary file in the same folder, flushed, then renamed.
/// Readers never see a partial file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    use std::io::Write;
    let parent = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    let file_name = path
        .file_name()
        .ok_or_else(|| Error::format(path, "not a file path"))?;
    let tmp = parent.join(format!(
        ".{}.{}.tmp",
        file_name.to_string_lossy(),
        std::process::id()
    ));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(Error::io(path, e));
    }
    Ok(())
}

/// Read a whole file, naming it in the error.
pub fn read_file(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|e| Error::io(path, e))
}

/// Lower-case hex SHA-256 of `bytes`.
pub fn sha256_hex(bytes: &[u8]) -> String {
    let digest = Sha256::digest(bytes);
    digest.iter().map(|b| format!("{b:02x}")).collect()
}

/// The f32 value of IEEE half-precision bits (exact: every half is an f32).
pub fn f16_bits_to_f32(h: u16) -> f32 {
    let negative = h & 0x8000 != 0;
    let exponent = u32::from((h >> 10) & 0x1f);
    let mantissa = u32::from(h & 0x3ff);
    let magnitude = match exponent {
        // Zero and subnormals: mantissa · 2⁻²⁴, exact in f32.
        0 => mantissa as f32 * (1.0 / 16_777_216.0),
        // Infinities and NaNs.
        0x1f => f32::from_bits(0x7f80_0000 | (mantissa << 13)),
        // Normal numbers: rebias the exponent (15 → 127), widen the mantissa.
        _ => f32::from_bits(((exponent + 112) << 23) | (mantissa << 13)),
    };
    if negative { -magnitude } else { magnitude }
}

/// A tensor to be written: name, dtype, shape and little-endian bytes.
#[derive(Clone, Debug)]
pub struct OwnedTensor {
    dtype: Dtype,
    shape: Vec<usize>,
    bytes: Vec<u8>,
}

impl OwnedTensor {
    /// An f32 tensor.
    pub fn f32(shape: &[usize], values: impl IntoIterator<Item = f32>) -> Self {
        let bytes: Vec<u8> = values.into_iter().flat_map(f32::to_le_bytes).collect();
        Self {
            dtype: Dtype::F32,
            shape: shape.to_vec(),
            bytes,
        }
    }

    /// An f16 tensor from raw IEEE half bits.
    pub fn f16_bits(shape: &[usize], values: impl IntoIterator<Item = u16>) -> Self {
        let bytes: Vec<u8> = values.into_iter().flat_map(u16::to_le_bytes).collect();
        Self {
            dtype: Dtype::F16,
            shape: shape.to_vec(),
            bytes,
        }
    }

    /// An i8 tensor.
    pub fn i8(shape: &[usize], values: impl IntoIterator<Item = i8>) -> Self {
        let bytes: Vec<u8> = values.into_iter().map(|v| v as u8).collect();
        Self {
            dtype: Dtype::I8,
            shape: shape.to_vec(),
            bytes,
        }
    }

    /// An i32 tensor.
    pub fn i32(shape: &[usize], values: impl IntoIterator<Item = i32>) -> Self {
        let bytes: Vec<u8> = values.into_iter().flat_map(i32::to_le_bytes).collect();
        Self {
            dtype: Dtype::I32,
            shape: shape.to_vec(),
            bytes,
        }
    }

    /// Points as an f32 `[n, 3]` tensor (f64 coordinates rounded to f32).
    pub fn points<T: nalgebra::Scalar + Copy + Into<f64>>(points: &[Vector3<T>]) -> Self {
        Self::f32(
            &[points.len(), 3],
            points
                .iter()
                .flat_map(|p| [p[0].into() as f32, p[1].into() as f32, p[2].into() as f32]),
        )
    }

    /// Index tuples (triangles, hinges) as an i32 `[n, K]` tensor.
    pub fn indices<const K: usize>(tuples: &[[u32; K]]) -> Self {
        Self::i32(
            &[tuples.len(), K],
            tuples.iter().flatten().map(|&i| i as i32),
        )
    }
}

/// Serialise named tensors to safetensors bytes (deterministic: names sorted, no metadata map
/// unless given, and the given map is sorted).
pub fn serialize_tensors(
    tensors: &BTreeMap<String, OwnedTensor>,
    metadata: Option<&BTreeMap<String, String>>,
) -> Result<Vec<u8>> {
    let mut views = Vec::with_capacity(tensors.len());
    for (name, t) in tensors {
        let view = TensorView::new(t.dtype, t.shape.clone(), &t.bytes)
            .map_err(|e| Error::invalid("tensor", format!("{name}: {e}")))?;
        views.push((name.clone(), view));
    }
    let info = metadata.map(|m| m.iter().map(|(k, v)| (k.clone(), v.clone())).collect());
    safetensors::serialize(views, info).map_err(|e| Error::invalid("tensor file", e.to_string()))
}

/// A safetensors file held in memory, with accessors that check dtype and shape and name the file
/// and tensor in every error.
pub struct TensorFile {
    path: PathBuf,
    bytes: Vec<u8>,
}

impl TensorFile {
    /// Read and parse the header of `path`.
    pub fn open(path: &Path) -> Result<Self> {
        let bytes = read_file(path)?;
        Self::from_bytes(path, bytes)
    }

    /// Parse bytes already read from `path`.
    pub fn from_bytes(path: &Path, bytes: Vec<u8>) -> Result<Self> {
        SafeTensors::deserialize(&bytes)
            .map_err(|e| Error::format(path, format!("not a safetensors file: {e}")))?;
        Ok(Self {
            path: path.to_path_buf(),
            bytes,
        })
    }

    /// The file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn tensors(&self) -> SafeTensors<'_> {
        SafeTensors::deserialize(&self.bytes)
            .expect("header was validated in TensorFile::from_bytes")
    }

    /// Names of all tensors, sorted.
    pub fn names(&self) -> Vec<String> {
        let mut names: Vec<String> = self
            .tensors()
            .names()
            .into_iter()
            .map(|s| s.to_string())
            .collect();
        names.sort();
        names
    }

    /// The `__metadata__` map of the header, if any.
    pub fn metadata(&self) -> Result<BTreeMap<String, String>> {
        let (_, meta) = SafeTensors::read_metadata(&self.bytes)
            .map_err(|e| Error::format(&self.path, format!("bad header: {e}")))?;
        Ok(meta
            .metadata()
            .clone()
            .map(|m| m.into_iter().collect())
            .unwrap_or_default())
    }

    /// Shape of a tensor.
    pub fn shape(&self, name: &str) -> Result<Vec<usize>> {
        let t = self.tensors();
        let view = t
            .tensor(name)
            .map_err(|_| Error::format(&self.path, format!("missing tensor {name:?}")))?;
        Ok(view.shape().to_vec())
    }

    fn raw(
        &self,
        name: &str,
        dtype: Dtype,
        shape: &[Option<usize>],
    ) -> Result<(Vec<usize>, Vec<u8>)> {
        let t = self.tensors();
        let view = t
            .tensor(name)
            .map_err(|_| Error::format(&self.path, format!("missing tensor {name:?}")))?;
        if view.dtype() != dtype {
            return Err(Error::format(
                &self.path,
                format!(
                    "tensor {name:?} has dtype {:?}, expected {dtype:?}",
                    view.dtype()
                ),
            ));
        }
        let got = view.shape();
        let matches = got.len() == shape.len()
            && got
                .iter()
                .zip(shape)
                .all(|(g, s)| s.is_none_or(|s| s == *g));
        if !matches {
            let want: Vec<String> = shape
                .iter()
                .map(|s| s.map_or("*".into(), |s| s.to_string()))
                .collect();
            return Err(Error::format(
                &self.path,
                format!(
                    "tensor {name:?} has shape {got:?}, expected [{}]",
                    want.join(", ")
                ),
            ));
        }
        Ok((got.to_vec(), view.data().to_vec()))
    }

    /// An f32 tensor with the expected shape (`None` = any size on that axis). Rejects
    /// non-finite values.
    pub fn f32(&self, name: &str, shape: &[Option<usize>]) -> Result<(Vec<usize>, Vec<f32>)> {
        let (s, bytes) = self.raw(name, Dtype::F32, shape)?;
        let v: Vec<f32> = bytes
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        if let Some(i) = v.iter().position(|x| !x.is_finite()) {
            return Err(Error::format(
                &self.path,
                format!("tensor {name:?} has a non-finite value at {i}"),
            ));
        }
        Ok((s, v))
    }

    /// An f32 tensor, or an f16 one widened to f32 (exactly: every half is an f32), with the
    /// expected shape. Rejects non-finite values. For files that store some tensors in half
    /// precision to be small on the wire (a model shipped to a web page).
    pub fn f32_or_f16(
        &self,
        name: &str,
        shape: &[Option<usize>],
    ) -> Result<(Vec<usize>, Vec<f32>)> {
        let t = self.tensors();
        let is_f16 = t.tensor(name).is_ok_and(|v| v.dtype() == Dtype::F16);
        if !is_f16 {
            return self.f32(name, shape);
        }
        let (s, bits) = self.f16_bits(name, shape)?;
        let v: Vec<f32> = bits.into_iter().map(f16_bits_to_f32).collect();
        if let Some(i) = v.iter().position(|x| !x.is_finite()) {
            return Err(Error::format(
                &self.path,
                format!("tensor {name:?} has a non-finite value at {i}"),
            ));
        }
        Ok((s, v))
    }

    /// An f16 tensor as raw IEEE half bits.
    pub fn f16_bits(&self, name: &str, shape: &[Option<usize>]) -> Result<(Vec<usize>, Vec<u16>)> {
        let (s, bytes) = self.raw(name, Dtype::F16, shape)?;
        Ok((
            s,
            bytes
                .chunks_exact(2)
                .map(|c| u16::from_le_bytes([c[0], c[1]]))
                .collect(),
        ))
    }

    /// An i8 tensor.
    pub fn i8(&self, name: &str, shape: &[Option<usize>]) -> Result<(Vec<usize>, Vec<i8>)> {
        let (s, bytes) = self.raw(name, Dtype::I8, shape)?;
        Ok((s, bytes.into_iter().map(|b| b as i8).collect()))
    }

    /// An i32 tensor.
    pub fn i32(&self, name: &str, shape: &[Option<usize>]) -> Result<(Vec<usize>, Vec<i32>)> {
        let (s, bytes) = self.raw(name, Dtype::I32, shape)?;
        Ok((
            s,
            bytes
                .chunks_exact(4)
                .map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect(),
        ))
    }

    /// An f32 `[n, 3]` tensor of points (`n` = `rows` when given), as f64.
    pub fn points(&self, name: &str, rows: Option<usize>) -> Result<Vec<Vector3<f64>>> {
        let (_, values) = self.f32(name, &[rows, Some(3)])?;
        Ok(values
            .chunks_exact(3)
            .map(|c| Vector3::new(c[0] as f64, c[1] as f64, c[2] as f64))
            .collect())
    }

    /// A non-negative i32 `[n, K]` tensor of index tuples (`n` = `rows` when given); the
    /// caller checks the indices' range (a mesh or binding constructor does).
    pub fn indices<const K: usize>(
        &self,
        name: &str,
        rows: Option<usize>,
    ) -> Result<Vec<[u32; K]>> {
        let (_, values) = self.u32(name, &[rows, Some(K)])?;
        Ok(values
            .chunks_exact(K)
            .map(|c| std::array::from_fn(|k| c[k]))
            .collect())
    }

    /// A non-negative i32 tensor (indices, offsets) as u32.
    pub fn u32(&self, name: &str, shape: &[Option<usize>]) -> Result<(Vec<usize>, Vec<u32>)> {
        let (s, values) = self.i32(name, shape)?;
        let values = values
            .into_iter()
            .map(|x| {
                u32::try_from(x).map_err(|_| {
                    Error::format(
                        &self.path,
                        format!("tensor {name:?} has a negative value {x}"),
                    )
                })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok((s, values))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn half_bits_widen_exactly() {
        for (bits, value) in [
            (0x0000, 0.0f32),
            (0x3c00, 1.0),
            (0xc000, -2.0),
            (0x3555, 0.333_251_95),
            (0x7bff, 65504.0),
            (0x0400, 2f32.powi(-14)),
            (0x0001, 2f32.powi(-24)),
            (0x83ff, -(1023.0 * 2f32.powi(-24))),
            (0x7c00, f32::INFINITY),
        ] {
            assert_eq!(f16_bits_to_f32(bits), value, "{bits:#06x}");
        }
        assert!(f16_bits_to_f32(0x7e00).is_nan());
        assert!(f16_bits_to_f32(0x8000).is_sign_negative());
    }

    #[test]
    fn f32_or_f16_reads_either_and_rejects_infinity() {
        let mut map = BTreeMap::new();
        map.insert("a".to_string(), OwnedTensor::f32(&[2], [1.5, -0.25]));
        map.insert(
            "h".to_string(),
            OwnedTensor::f16_bits(&[2], [0x3e00, 0xb400]),
        );
        map.insert("inf".to_string(), OwnedTensor::f16_bits(&[1], [0x7c00]));
        let bytes = serialize_tensors(&map, None).expect("serialises");
        let file = TensorFile::from_bytes(Path::new("t.safetensors"), bytes).expect("parses");
        assert_eq!(
            file.f32_or_f16("a", &[Some(2)]).expect("f32").1,
            [1.5, -0.25]
        );
        assert_eq!(
            file.f32_or_f16("h", &[Some(2)]).expect("f16").1,
            [1.5, -0.25]
        );
        let err = file.f32_or_f16("inf", &[None]).expect_err("infinite");
        assert!(err.to_string().contains("non-finite"), "{err}");
        assert!(file.f32_or_f16("h", &[Some(3)]).is_err());
        assert!(file.f32("h", &[Some(2)]).is_err(), "f32 alone stays strict");
    }
}
