//! Timing of runtime frames, and the one median every speed report uses.

use std::time::Instant;

use sartor_core::Pose;
use sartor_runtime::GarmentAnimator;

use crate::Result;

/// Timings of a run of frames.
#[derive(Clone, Debug)]
pub struct FrameTiming {
    /// Wall time per frame, ms.
    pub wall_ms: Vec<f64>,
    /// Mean CPU time of the calling thread per frame, ms (meaningful for one thread only;
    /// `None` where the platform does not say).
    pub cpu_ms: Option<f64>,
}

/// CPU time of the calling thread, nanoseconds (Linux `schedstat`; `None` elsewhere). Unlike
/// wall time it does not count the time other processes hold the core, so single-thread
/// figures stay comparable on a loaded machine.
pub fn thread_cpu_ns() -> Option<u64> {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// Time `frames` frames of `avatar` after `warmup` untimed ones, cycling through `poses`. The
/// avatar keeps its shape and recurrent state: call `reset`/`reset_from` before if needed.
pub fn time_frames(
    avatar: &mut GarmentAnimator,
    poses: &[Pose],
    warmup: usize,
    frames: usize,
) -> Result<FrameTiming> {
    crate::error::ensure!(!poses.is_empty(), "no poses to time");
    let mut wall_ms = Vec::with_capacity(frames);
    let mut cpu_start = None;
    for t in 0..warmup + frames {
        if t == warmup {
            cpu_start = thread_cpu_ns();
        }
        let pose = &poses[t % poses.len()];
        let start = Instant::now();
        std::hint::black_box(avatar.frame(pose)?);
        if t >= warmup {
            wall_ms.push(start.elapsed().as_secs_f64() * 1e3);
        }
    }
    let cpu_ms = match (cpu_start, thread_cpu_ns()) {
        (Some(a), Some(b)) => Some((b - a) as f64 / 1e6 / frames.max(1) as f64),
        _ => None,
    };
    Ok(FrameTiming { wall_ms, cpu_ms })
}

/// The median (the mean of the two middle values for an even count; NaN when empty).
pub fn median(values: &[f64]) -> f64 {
    let mut s = values.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

/// The mean (NaN when empty).
pub fn mean(values: &[f64]) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.iter().sum::<f64>() / values.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_and_mean() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), 2.5);
        assert!(median(&[]).is_nan());
        assert_eq!(mean(&[1.0, 2.0, 6.0]), 3.0);
        assert!(mean(&[]).is_nan());
    }
}
