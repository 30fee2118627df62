//! Reading numeric arrays from NumPy `.npz` archives (SMPL models, AMASS motions), converting
//! any float or integer dtype to f64 and naming the file and array in every error. An archive
//! is a zip of `<name>.npy` files, stored or deflated (`np.savez`, `np.savez_compressed`).

use std::path::{Path, PathBuf};

use npyz::{DType, TypeChar};

use crate::{Error, Result};

/// An open `.npz` archive.
pub struct NpzFile {
    path: PathBuf,
    archive: zip::ZipArchive<std::io::Cursor<Vec<u8>>>,
}

impl NpzFile {
    /// Open an archive.
    pub fn open(path: &Path) -> Result<Self> {
        Self::from_bytes(path, sartor_core::io::read_file(path)?)
    }

    /// Parse an archive already read from `path` (used in error messages only).
    pub fn from_bytes(path: &Path, bytes: Vec<u8>) -> Result<Self> {
        let archive = zip::ZipArchive::new(std::io::Cursor::new(bytes))
            .map_err(|e| Error::format(path, format!("not a readable .npz archive: {e}")))?;
        Ok(Self {
            path: path.to_path_buf(),
            archive,
        })
    }

    /// The file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The arrays' names, as the archive lists them.
    fn array_names(&self) -> impl Iterator<Item = &str> {
        self.archive
            .file_names()
            .filter_map(npyz::npz::array_name_from_file_name)
    }

    /// Names of the arrays, sorted.
    pub fn names(&self) -> Vec<String> {
        let mut n: Vec<String> = self.array_names().map(str::to_string).collect();
        n.sort();
        n
    }

    /// Whether an array exists.
    pub fn contains(&self, name: &str) -> bool {
        self.array_names().any(|n| n == name)
    }

    /// An array as f64 in C order, with its shape. Accepts little- or big-endian f2/f4/f8, signed
    /// and unsigned 1–8-byte integers and booleans; rejects non-finite values and Fortran order
    /// (transposed on the fly would hide a layout mistake; SMPL files are C order).
    pub fn array_f64(&mut self, name: &str) -> Result<(Vec<usize>, Vec<f64>)> {
        let path = self.path.clone();
        let fault = |m: String| Error::format(&path, format!("array {name:?}: {m}"));
        let entry = match self
            .archive
            .by_name(&npyz::npz::file_name_from_array_name(name))
        {
            Ok(entry) => entry,
            Err(zip::result::ZipError::FileNotFound) => {
                return Err(Error::format(&path, format!("missing array {name:?}")));
            }
            Err(e) => return Err(fault(format!("cannot read: {e}"))),
        };
        let npy = npyz::NpyFile::new(entry).map_err(|e| fault(format!("cannot read: {e}")))?;
        let shape: Vec<usize> = npy.shape().iter().map(|&s| s as usize).collect();
        if npy.order() == npyz::Order::Fortran && shape.len() > 1 {
            return Err(fault(
                "Fortran-ordered arrays are not supported; save with np.ascontiguousarray".into(),
            ));
        }
        let DType::Plain(ts) = npy.dtype() else {
            return Err(fault("structured dtypes are not supported".into()));
        };
        let size = ts.size_field();
        let read_err = |e: std::io::Error| fault(format!("truncated or unreadable data: {e}"));
        let values: Vec<f64> = match (ts.type_char(), size) {
            (TypeChar::Float, 8) => npy.into_vec::<f64>().map_err(read_err)?,
            (TypeChar::Float, 4) => npy
                .into_vec::<f32>()
                .map_err(read_err)?
                .into_iter()
                .map(f64::from)
                .collect(),
            (TypeChar::Int, 8) => npy
                .into_vec::<i64>()
                .map_err(read_err)?
                .into_iter()
                .map(|x| x as f64)
                .collect(),
            (TypeChar::Int, 4) => npy
                .into_vec::<i32>()
                .map_err(read_err)?
                .into_iter()
                .map(f64::from)
                .collect(),
            (TypeChar::Int, 2) => npy
                .into_vec::<i16>()
                .map_err(read_err)?
                .into_iter()
                .map(f64::from)
                .collect(),
            (TypeChar::Int, 1) => npy
                .into_vec::<i8>()
                .map_err(read_err)?
                .into_iter()
                .map(f64::from)
                .collect(),
            (TypeChar::Uint, 8) => npy
                .into_vec::<u64>()
                .map_err(read_err)?
                .into_iter()
                .map(|x| x as f64)
                .collect(),
            (TypeChar::Uint, 4) => npy
                .into_vec::<u32>()
                .map_err(read_err)?
                .into_iter()
                .map(f64::from)
                .collect(),
            (TypeChar::Uint, 2) => npy
                .into_vec::<u16>()
                .map_err(read_err)?
                .into_iter()
                .map(f64::from)
                .collect(),
            (TypeChar::Uint, 1) => npy
                .into_vec::<u8>()
                .map_err(read_err)?
                .into_iter()
                .map(f64::from)
                .collect(),
            (TypeChar::Bool, 1) => npy
                .into_vec::<bool>()
                .map_err(read_err)?
                .into_iter()
                .map(|b| f64::from(u8::from(b)))
                .collect(),
            _ => return Err(fault(format!("unsupported dtype {ts}"))),
        };
        if values.len() != shape.iter().product::<usize>() {
            return Err(fault(format!(
                "{} values for shape {shape:?}",
                values.len()
            )));
        }
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(fault(format!("non-finite value at flat index {i}")));
        }
        Ok((shape, values))
    }

    /// Like [`Self::array_f64`], checking the shape (`None` = any size on that axis).
    pub fn array_f64_shaped(
        &mut self,
        name: &str,
        expected: &[Option<usize>],
    ) -> Result<(Vec<usize>, Vec<f64>)> {
        let (shape, values) = self.array_f64(name)?;
        let ok = shape.len() == expected.len()
            && shape
                .iter()
                .zip(expected)
                .all(|(s, e)| e.is_none_or(|e| e == *s));
        if !ok {
            let want: Vec<String> = expected
                .iter()
                .map(|e| e.map_or("*".into(), |e| e.to_string()))
                .collect();
            return Err(Error::format(
                &self.path,
                format!(
                    "array {name:?} has shape {shape:?}, expected [{}]",
                    want.join(", ")
                ),
            ));
        }
        Ok((shape, values))
    }
}
