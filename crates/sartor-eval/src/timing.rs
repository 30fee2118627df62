//! Timing of runtime frames, and the one median every speed report uses.

use std::time::Instant;

use sartor_core::Pose;
use sartor_runtime::{GarmentAnimator, StageTimes};

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

/// CPU time of the calling thread, nanoseconds (Linux `CLOCK_THREAD_CPUTIME_ID`; `None`
/// elsewhere). Unlike wall time it does not count the time other processes hold the core, so
/// single-thread figures stay comparable on a loaded machine. Not `/proc/thread-self/schedstat`,
/// which it read before: a running thread's figure there moves only at the scheduler's tick
/// (4 ms on the AMD EPYC VM), so 120 frames of 1 ms read in steps of 0.033 ms, and a
/// difference of two such runs (a stage's share) was off by up to twice that.
#[cfg(target_os = "linux")]
#[allow(unsafe_code)]
pub fn thread_cpu_ns() -> Option<u64> {
    let mut t = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `t` is a valid, writable timespec; the call writes only it.
    let ok = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut t) } == 0;
    ok.then(|| t.tv_sec as u64 * 1_000_000_000 + t.tv_nsec as u64)
}

/// CPU time of the calling thread: not read off Linux.
#[cfg(not(target_os = "linux"))]
pub fn thread_cpu_ns() -> Option<u64> {
    None
}

/// Time `frames` frames of `avatar` after `warmup` untimed ones, cycling through `poses`. The
/// avatar keeps its shape and recurrent state: call `reset`/`reset_from` before if needed.
pub fn time_frames(
    avatar: &mut GarmentAnimator,
    poses: &[Pose],
    warmup: usize,
    frames: usize,
) -> Result<FrameTiming> {
    time_each(avatar, poses, warmup, frames, |_| {})
}

/// [`time_frames`], and the mean CPU time per stage of the timed frames by the thread clock
/// (`None` where there is none): a stage's own time read inside the frame, not the difference
/// of two runs. The clock is read at each stage's ends, each a system call of about a
/// microsecond (not in the vDSO), which the frame timings carry too: for the post-process's
/// share, not for a network of tens of microseconds. Leaves the avatar's stage clock off.
pub fn time_stages(
    avatar: &mut GarmentAnimator,
    poses: &[Pose],
    warmup: usize,
    frames: usize,
) -> Result<(FrameTiming, Option<StageTimes>)> {
    if thread_cpu_ns().is_none() {
        return Ok((time_frames(avatar, poses, warmup, frames)?, None));
    }
    avatar.set_stage_clock(Some(thread_cpu_ms));
    let mut sum = StageTimes::default();
    let timing = time_each(avatar, poses, warmup, frames, |a| {
        let t = a.stage_times().unwrap_or_default();
        sum.network_ms += t.network_ms;
        sum.skinning_ms += t.skinning_ms;
        sum.strain_limit_ms += t.strain_limit_ms;
        sum.post_process_ms += t.post_process_ms;
    });
    avatar.set_stage_clock(None);
    let n = frames.max(1) as f64;
    let mean = StageTimes {
        network_ms: sum.network_ms / n,
        skinning_ms: sum.skinning_ms / n,
        strain_limit_ms: sum.strain_limit_ms / n,
        post_process_ms: sum.post_process_ms / n,
    };
    Ok((timing?, Some(mean)))
}

/// The thread clock in milliseconds, for [`GarmentAnimator::set_stage_clock`] (NaN without one).
fn thread_cpu_ms() -> f64 {
    thread_cpu_ns().map_or(f64::NAN, |ns| ns as f64 * 1e-6)
}

/// [`time_frames`], calling `timed` after each timed frame.
fn time_each(
    avatar: &mut GarmentAnimator,
    poses: &[Pose],
    warmup: usize,
    frames: usize,
    timed: impl FnMut(&GarmentAnimator),
) -> Result<FrameTiming> {
    crate::error::ensure!(!poses.is_empty(), "no poses to time");
    let frame = |a: &mut GarmentAnimator, t: usize| {
        std::hint::black_box(a.frame(&poses[t % poses.len()])?);
        Ok(())
    };
    time_calls(avatar, warmup, frames, frame, timed)
}

/// Time `frames` calls of `frame(subject, t)` after `warmup` untimed ones (`t` counts from 0
/// over all of them), calling `timed(subject)` after each timed one, outside its wall time
/// (inside the CPU mean). A frame of anything: one avatar, a crowd.
pub fn time_calls<S>(
    subject: &mut S,
    warmup: usize,
    frames: usize,
    mut frame: impl FnMut(&mut S, usize) -> Result<()>,
    mut timed: impl FnMut(&S),
) -> Result<FrameTiming> {
    let mut wall_ms = Vec::with_capacity(frames);
    let mut cpu_start = None;
    for t in 0..warmup + frames {
        if t == warmup {
            cpu_start = thread_cpu_ns();
        }
        let start = Instant::now();
        frame(subject, t)?;
        if t >= warmup {
            wall_ms.push(start.elapsed().as_secs_f64() * 1e3);
            timed(subject);
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

    /// The thread clock moves with the work, finer than a scheduler tick: 300 µs of spinning
    /// read as more than nothing and no more than the wall time it took (a tick-driven
    /// clock reads 0 or a whole tick of 1–10 ms).
    #[cfg(target_os = "linux")]
    #[test]
    fn the_thread_clock_resolves_a_fraction_of_a_millisecond() {
        let cpu = thread_cpu_ns().expect("a thread clock on Linux");
        let wall = Instant::now();
        let mut x = 1u64;
        while wall.elapsed().as_micros() < 300 {
            x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
        }
        let spent = thread_cpu_ns().expect("a thread clock") - cpu;
        let elapsed = wall.elapsed().as_nanos() as u64;
        assert!(
            spent > 0 && spent <= elapsed + 50_000,
            "{spent} ns of CPU in {elapsed} ns"
        );
    }

    #[test]
    fn median_and_mean() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), 2.5);
        assert!(median(&[]).is_nan());
        assert_eq!(mean(&[1.0, 2.0, 6.0]), 3.0);
        assert!(mean(&[]).is_nan());
    }
}
