//! What every report carries: the machine it was made on (reports with timings say where they
//! were taken), and atomic JSON writing.

use serde::Serialize;

use crate::{Error, Result};

/// Cores and CPU model.
#[derive(Clone, Debug, Serialize)]
pub struct Machine {
    /// Logical cores available to this process.
    pub cores: usize,
    /// `model name` from /proc/cpuinfo ("unknown" elsewhere).
    pub cpu_model: String,
}

impl Machine {
    /// This machine.
    pub fn current() -> Self {
        let cpu_model = std::fs::read_to_string("/proc/cpuinfo")
            .ok()
            .and_then(|s| {
                s.lines()
                    .find(|l| l.starts_with("model name"))
                    .and_then(|l| l.split(':').nth(1))
                    .map(|m| m.trim().to_string())
            })
            .unwrap_or_else(|| "unknown".into());
        Self {
            cores: std::thread::available_parallelism().map_or(1, |n| n.get()),
            cpu_model,
        }
    }
}

/// The 1, 5 and 15 minute load averages (as `uptime` prints them), if /proc/loadavg exists.
pub fn load_average() -> Option<[f64; 3]> {
    let text = std::fs::read_to_string("/proc/loadavg").ok()?;
    let mut fields = text.split_whitespace().map(|f| f.parse::<f64>().ok());
    Some([fields.next()??, fields.next()??, fields.next()??])
}

/// Write `value` as pretty JSON (with a final newline) atomically.
pub fn write_json(path: &std::path::Path, value: &impl Serialize) -> Result<()> {
    let mut json = serde_json::to_string_pretty(value).map_err(|e| Error::Write {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    json.push('\n');
    sartor_core::io::write_atomic(path, json.as_bytes())?;
    Ok(())
}

/// Read a JSON file (`None` when it is missing or not JSON): for summaries of optional reports.
pub fn read_json(path: &std::path::Path) -> Option<serde_json::Value> {
    serde_json::from_slice(&std::fs::read(path).ok()?).ok()
}
