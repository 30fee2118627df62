//! Shared fixtures of the importers' tests (the geometry core's random poses and stand-in body
//! are `crate::core_fixtures`).

/// Where two JSON documents differ beyond `tol` in any number (or at all elsewhere), the path of
/// the first difference. Committed imports are compared this way: libm's transcendental
/// functions may round the last bit differently on another CPU.
pub fn json_difference(a: &serde_json::Value, b: &serde_json::Value, tol: f64) -> Option<String> {
    use serde_json::Value;
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64()?, y.as_f64()?);
            let scale = x.abs().max(y.abs()).max(1.0);
            ((x - y).abs() > tol * scale).then(|| format!(": {x} vs {y}"))
        }
        (Value::Array(x), Value::Array(y)) => {
            if x.len() != y.len() {
                return Some(format!(": {} vs {} items", x.len(), y.len()));
            }
            x.iter()
                .zip(y)
                .enumerate()
                .find_map(|(i, (x, y))| json_difference(x, y, tol).map(|d| format!("[{i}]{d}")))
        }
        (Value::Object(x), Value::Object(y)) => {
            if x.len() != y.len() || x.keys().any(|k| !y.contains_key(k)) {
                return Some(": different keys".to_owned());
            }
            x.iter()
                .find_map(|(k, v)| json_difference(v, &y[k], tol).map(|d| format!(".{k}{d}")))
        }
        _ => (a != b).then(|| format!(": {a} vs {b}")),
    }
}

/// The built-in body model folder of the workspace (`datasets/body/makehuman`).
pub fn builtin_model_dir() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../datasets/body/makehuman")
}

/// The built-in body model.
pub fn load_builtin() -> sartor_core::Result<sartor_core::BodyModel> {
    sartor_core::BodyModel::load(&builtin_model_dir())
}
