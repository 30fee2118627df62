//! The clip catalogue: one generator per clip, `t` in seconds (already scaled by the seed's rate).

use std::f64::consts::{PI, TAU};

use super::{Arm, ClipDef, Jitter, Leg, Params};

/// Four dynamic clips held out as test motions (as the paper held out 4 of its 56): a jump, a
/// dance, fast arm motion and a run.
pub const HELD_OUT_CLIPS: [&str; 4] = [
    "jump_forward",
    "dance_disco",
    "arm_circles_fast",
    "run_fast",
];

fn d(deg: f64) -> f64 {
    deg.to_radians()
}

/// `sin(2π·hz·t + phase)`.
fn sw(t: f64, hz: f64, phase: f64) -> f64 {
    (TAU * hz * t + phase).sin()
}

/// `cos(2π·hz·t + phase)`.
fn cw(t: f64, hz: f64, phase: f64) -> f64 {
    (TAU * hz * t + phase).cos()
}

/// `((1 + cos x) / 2)^n`: a smooth non-negative bump peaking at `x = 0 (mod 2π)`.
fn bump(x: f64, n: i32) -> f64 {
    (0.5 * (1.0 + x.cos())).powi(n)
}

/// `sin²(π u)` on `u ∈ [0, 1]`, zero outside: a C1 pulse.
fn pulse(u: f64) -> f64 {
    if (0.0..=1.0).contains(&u) {
        (PI * u).sin().powi(2)
    } else {
        0.0
    }
}

/// A repeating pulse: `pulse` over `[start, start + width]` of every `period` (fractions of it).
fn beat(t: f64, period: f64, start: f64, width: f64) -> f64 {
    let u = (t / period).rem_euclid(1.0);
    pulse((u - start) / width) + pulse((u - start + 1.0) / width)
}

/// Arms relaxed along the body (hanging, elbows slightly bent).
fn relaxed_arms() -> [Arm; 2] {
    let a = Arm {
        abd: d(-38.0),
        elbow: d(12.0),
        ..Arm::default()
    };
    [a, a]
}

fn standing() -> Params {
    Params {
        arms: relaxed_arms(),
        ..Params::default()
    }
}

/// A gait: walking, running, marching.
#[derive(Clone, Copy)]
struct Gait {
    /// Stride cycles per second (two steps each).
    hz: f64,
    /// Ground speed along the heading, m/s (negative: backward).
    speed: f64,
    hip: f64,
    hip_offset: f64,
    knee_swing: f64,
    knee_stance: f64,
    ankle: f64,
    arm: f64,
    elbow: f64,
    elbow_swing: f64,
    pelvis_yaw: f64,
    pelvis_roll: f64,
    lean: f64,
    /// Flight lift per step (runs, skips), metres.
    bounce: f64,
}

const WALK: Gait = Gait {
    hz: 0.9,
    speed: 1.15,
    hip: 0.36,
    hip_offset: 0.05,
    knee_swing: 1.05,
    knee_stance: 0.18,
    ankle: 0.3,
    arm: 0.3,
    elbow: 0.2,
    elbow_swing: 0.25,
    pelvis_yaw: 0.08,
    pelvis_roll: 0.05,
    lean: 0.05,
    bounce: 0.0,
};

const RUN: Gait = Gait {
    hz: 1.35,
    speed: 3.0,
    hip: 0.6,
    hip_offset: 0.2,
    knee_swing: 1.9,
    knee_stance: 0.45,
    ankle: 0.45,
    arm: 0.55,
    elbow: 1.35,
    elbow_swing: 0.2,
    pelvis_yaw: 0.12,
    pelvis_roll: 0.05,
    lean: 0.15,
    bounce: 0.045,
};

fn gait(t: f64, g: &Gait, j: &Jitter) -> Params {
    let mut p = standing();
    let a = j.amp;
    let base = TAU * g.hz * t + j.phase;
    for side in 0..2 {
        let phi = base + side as f64 * PI;
        // Backward walking plays the leg cycle in reverse.
        let phi = if g.speed < 0.0 { -phi } else { phi };
        p.legs[side] = Leg {
            hip_flex: a * (g.hip * phi.sin() + g.hip_offset),
            hip_abd: 0.0,
            hip_rot: d(4.0),
            knee: a
                * (g.knee_swing * bump(phi + 0.25, 2) + g.knee_stance * bump(phi - PI + 0.7, 4)),
            ankle: a * (g.ankle * bump(phi + 1.75, 4) - 0.35 * g.ankle * bump(phi - 0.4, 2)),
            toe: a * 0.7 * g.ankle * bump(phi + 1.95, 6),
        };
        let arm_phase = base + side as f64 * PI;
        p.arms[side].flex = -a * g.arm * arm_phase.sin();
        p.arms[side].elbow = a * (g.elbow + g.elbow_swing * 0.5 * (1.0 - arm_phase.sin()));
        p.arms[side].abd = d(-36.0);
    }
    p.pelvis = [
        g.lean * 0.4,
        a * g.pelvis_roll * (2.0 * base).sin() * 0.5,
        -a * g.pelvis_yaw * base.sin(),
    ];
    p.spine = [g.lean, 0.0, a * 1.4 * g.pelvis_yaw * base.sin()];
    p.neck = [-0.3 * g.lean, 0.0, -a * 0.4 * g.pelvis_yaw * base.sin()];
    p.forward_speed = g.speed * a;
    p.lift = g.bounce * a * bump(2.0 * base + 0.3, 2);
    p
}

fn scaled_gait(g: Gait, speed: f64, hz: f64, amp: f64) -> Gait {
    Gait {
        hz,
        speed,
        hip: g.hip * amp,
        knee_swing: g.knee_swing * amp,
        arm: g.arm * amp,
        ..g
    }
}

/// Stepping in place (turns, marches): legs lift, no forward speed.
fn step_in_place(t: f64, hz: f64, hip: f64, knee: f64, j: &Jitter) -> Params {
    let mut p = standing();
    for side in 0..2 {
        let phi = TAU * hz * t + j.phase + side as f64 * PI;
        let lift = bump(phi, 2);
        p.legs[side].hip_flex = j.amp * hip * lift;
        p.legs[side].knee = j.amp * knee * lift;
        p.legs[side].ankle = j.amp * 0.3 * hip * lift;
        p.arms[side].flex = -j.amp * 0.5 * hip * (phi + 0.0).cos() * 0.8;
        p.arms[side].abd = d(-36.0);
        p.arms[side].elbow = d(25.0);
    }
    p
}

/// One jump of the given period: crouch, flight, landing, as pulses of `u = t / period`.
/// Returns `(crouch, flight)` weights in `[0, 1]`.
fn jump_phase(t: f64, period: f64) -> (f64, f64) {
    let u = (t / period).rem_euclid(1.0);
    let crouch = pulse(u / 0.42) + pulse((u - 0.58) / 0.42);
    let flight = pulse((u - 0.33) / 0.34);
    (crouch, flight)
}

fn crouch_legs(p: &mut Params, c: f64, depth: f64) {
    for side in 0..2 {
        p.legs[side].hip_flex = depth * d(70.0) * c;
        p.legs[side].knee = depth * d(95.0) * c;
        p.legs[side].ankle = -depth * d(25.0) * c;
    }
    p.pelvis[0] = depth * d(15.0) * c;
    p.spine[0] = depth * d(20.0) * c;
}

fn jump(t: f64, j: &Jitter, period: f64, height: f64, forward: f64, turn: f64) -> Params {
    let mut p = standing();
    let (c, f) = jump_phase(t, period);
    crouch_legs(&mut p, c, j.amp);
    for side in 0..2 {
        p.legs[side].ankle += d(30.0) * f;
        p.legs[side].toe = d(15.0) * f;
        p.arms[side].flex = j.amp * (d(-35.0) * c + d(100.0) * f);
        p.arms[side].elbow = d(20.0) + d(15.0) * c;
    }
    p.lift = height * j.amp * f;
    // Forward travel and turn during the flight: the pulse integrates to half its width.
    p.forward_speed = forward * f / (0.5 * 0.34 * period);
    p.turn_rate = turn * f / (0.5 * 0.34 * period);
    p
}

fn reach(
    t: f64,
    j: &Jitter,
    hz: f64,
    arms: [Option<Arm>; 2],
    spine: [f64; 3],
    rise: f64,
) -> Params {
    let mut p = standing();
    // Never past the target pose: the seed only shortens the reach.
    let w = j.amp.min(1.0) * bump(TAU * hz * t + PI, 2);
    for side in 0..2 {
        if let Some(target) = arms[side] {
            let base = p.arms[side];
            p.arms[side] = Arm {
                clav_elev: base.clav_elev + w * (target.clav_elev - base.clav_elev),
                clav_fwd: w * target.clav_fwd,
                abd: base.abd + w * (target.abd - base.abd),
                flex: w * target.flex,
                horiz: w * target.horiz,
                twist: w * target.twist,
                elbow: base.elbow + w * (target.elbow - base.elbow),
                wrist: w * target.wrist,
            };
        }
    }
    p.spine = spine.map(|x| x * w);
    for side in 0..2 {
        p.legs[side].ankle = rise * w;
    }
    p.lift = 0.07 * (rise * w).sin();
    p
}

fn arm_swing(
    t: f64,
    j: &Jitter,
    hz: f64,
    amp_deg: f64,
    sides: [bool; 2],
    opposite: bool,
) -> Params {
    let mut p = standing();
    for side in 0..2 {
        if sides[side] {
            let ph = if opposite && side == 1 { PI } else { 0.0 };
            let s = sw(t, hz, j.phase + ph);
            p.arms[side].flex = j.amp * d(amp_deg) * s;
            p.arms[side].elbow = d(12.0) + d(20.0) * j.amp * 0.5 * (1.0 + s);
        }
    }
    p.spine[2] = if opposite {
        0.0
    } else {
        d(4.0) * sw(t, hz, j.phase)
    };
    p
}

fn arm_circles(t: f64, j: &Jitter, hz: f64, radius_deg: f64, sides: [bool; 2], dir: f64) -> Params {
    let mut p = standing();
    for side in 0..2 {
        if sides[side] {
            let ph = dir * TAU * hz * t + j.phase;
            p.arms[side].abd = d(45.0) + j.amp * d(radius_deg) * ph.sin();
            p.arms[side].horiz = j.amp * d(radius_deg) * ph.cos();
            p.arms[side].elbow = d(5.0);
            p.arms[side].clav_elev = d(5.0) + d(4.0) * ph.sin();
        }
    }
    p
}

fn twist(t: f64, j: &Jitter, hz: f64, amp_deg: f64) -> Params {
    let mut p = standing();
    let s = sw(t, hz, j.phase);
    p.spine[2] = j.amp * d(amp_deg) * s;
    p.pelvis[2] = -j.amp * d(amp_deg) * 0.25 * s;
    p.neck[2] = j.amp * d(amp_deg) * 0.3 * s;
    for side in 0..2 {
        p.arms[side].abd = d(20.0);
        p.arms[side].elbow = d(70.0);
        p.arms[side].horiz = d(35.0);
    }
    p
}

fn kick(t: f64, j: &Jitter, side: usize, period: f64, front: bool) -> Params {
    let mut p = standing();
    let u = (t / period).rem_euclid(1.0);
    let chamber = pulse(u / 0.7);
    let strike = pulse((u - 0.2) / 0.35);
    let other = 1 - side;
    if front {
        p.legs[side].hip_flex = j.amp * (d(45.0) * chamber + d(40.0) * strike);
        p.legs[side].knee = j.amp * (d(85.0) * chamber * (1.0 - strike) + d(10.0) * strike);
        p.legs[side].ankle = j.amp * d(20.0) * strike;
        p.spine[0] = -j.amp * d(10.0) * strike;
    } else {
        p.legs[side].hip_abd = j.amp * d(45.0) * (chamber * 0.6 + strike * 0.4);
        p.legs[side].hip_flex = j.amp * d(20.0) * chamber;
        p.legs[side].knee = j.amp * (d(70.0) * chamber * (1.0 - strike) + d(8.0) * strike);
        p.spine[1] = if side == 0 { -1.0 } else { 1.0 } * j.amp * d(15.0) * strike;
        p.pelvis[1] = if side == 0 { -1.0 } else { 1.0 } * j.amp * d(8.0) * chamber;
    }
    p.legs[other].knee = d(12.0) * chamber;
    p.legs[other].hip_flex = d(8.0) * chamber;
    for s in 0..2 {
        p.arms[s].elbow = d(80.0);
        p.arms[s].horiz = d(30.0);
        p.arms[s].abd = d(10.0) + d(20.0) * strike;
    }
    p
}

fn dance_base(t: f64, j: &Jitter, hz: f64, bounce_deg: f64) -> Params {
    let mut p = standing();
    let b = bump(TAU * 2.0 * hz * t + j.phase, 2);
    for side in 0..2 {
        p.legs[side].knee = j.amp * d(bounce_deg) * b;
        p.legs[side].hip_flex = j.amp * d(bounce_deg) * 0.5 * b;
        p.legs[side].ankle = -j.amp * d(bounce_deg) * 0.3 * b;
    }
    p
}

macro_rules! clips {
    ($($name:literal, $secs:expr, $f:expr;)*) => {
        /// All clips.
        pub(crate) const CLIPS: &[ClipDef] = &[$(ClipDef { name: $name, secs: $secs, build: $f }),*];
    };
}

clips! {
    // Locomotion.
    "walk_slow", 8.0, |t, j| gait(t, &scaled_gait(WALK, 0.75, 0.7, 0.8), j);
    "walk_normal", 8.0, |t, j| gait(t, &WALK, j);
    "walk_fast", 8.0, |t, j| gait(t, &scaled_gait(WALK, 1.7, 1.05, 1.2), j);
    "walk_backward", 8.0, |t, j| gait(t, &Gait { lean: -0.02, ..scaled_gait(WALK, -0.6, 0.75, 0.7) }, j);
    "walk_tiptoe", 8.0, |t, j| {
        let mut p = gait(t, &scaled_gait(WALK, 0.6, 0.95, 0.6), j);
        for l in &mut p.legs { l.ankle += d(22.0); }
        p.lift = 0.05;
        p
    };
    "walk_turn_left", 8.0, |t, j| Params { turn_rate: 0.45, ..gait(t, &WALK, j) };
    "walk_turn_right", 8.0, |t, j| Params { turn_rate: -0.45, ..gait(t, &WALK, j) };
    "walk_circle", 10.0, |t, j| Params { turn_rate: 0.8, ..gait(t, &scaled_gait(WALK, 0.9, 0.85, 0.9), j) };
    "walk_waving", 8.0, |t, j| {
        let mut p = gait(t, &WALK, j);
        p.arms[1] = Arm { abd: d(105.0), elbow: d(70.0), twist: d(28.0) * sw(t, 1.8, 0.0), clav_elev: d(10.0), ..Arm::default() };
        p
    };
    "run_jog", 8.0, |t, j| gait(t, &Gait { bounce: 0.035, ..scaled_gait(RUN, 2.2, 1.25, 0.75) }, j);
    "run_fast", 6.0, |t, j| gait(t, &Gait { bounce: 0.05, hip_offset: 0.15, ..scaled_gait(RUN, 3.8, 1.45, 0.9) }, j);
    "run_turn_left", 8.0, |t, j| Params { turn_rate: 0.7, ..gait(t, &RUN, j) };
    "run_in_place", 6.0, |t, j| gait(t, &Gait { speed: 0.0, hip_offset: 0.35, hip: 0.35, ..RUN }, j);
    "march_in_place", 8.0, |t, j| step_in_place(t, 0.8, d(65.0), d(80.0), j);
    "march_forward", 8.0, |t, j| Params { forward_speed: 0.7, ..step_in_place(t, 0.8, d(60.0), d(75.0), j) };
    "side_step_left", 8.0, |t, j| side_step(t, j, 1.0);
    "side_step_right", 8.0, |t, j| side_step(t, j, -1.0);
    "skip_forward", 8.0, |t, j| {
        let mut p = gait(t, &Gait { bounce: 0.08, ..scaled_gait(WALK, 1.6, 1.1, 1.1) }, j);
        for (side, a) in p.arms.iter_mut().enumerate() {
            a.flex = j.amp * d(60.0) * sw(t, 1.1, j.phase + if side == 0 { PI } else { 0.0 });
        }
        p
    };
    // Jumps.
    "jump_in_place", 7.0, |t, j| jump(t, j, 1.6, 0.28, 0.0, 0.0);
    "jump_forward", 7.0, |t, j| jump(t, j, 1.8, 0.3, 0.8, 0.0);
    "jump_twist", 7.0, |t, j| jump(t, j, 2.0, 0.32, 0.0, if (t / 2.0).rem_euclid(2.0) < 1.0 { PI / 2.0 } else { -PI / 2.0 });
    "jumping_jacks", 8.0, |t, j| {
        let mut p = standing();
        let open = bump(TAU * 0.85 * t + j.phase + PI, 2);
        for l in &mut p.legs {
            l.hip_abd = j.amp * d(18.0) * open;
            l.knee = d(10.0) * bump(TAU * 1.7 * t + j.phase, 2);
            l.ankle = d(15.0) * bump(TAU * 1.7 * t + j.phase + PI, 4);
        }
        for a in &mut p.arms {
            a.abd = d(-38.0) + j.amp * d(150.0) * open;
            a.elbow = d(10.0);
        }
        p.lift = 0.07 * bump(TAU * 1.7 * t + j.phase + PI, 2);
        p
    };
    "hop_left_foot", 7.0, |t, j| {
        let mut p = standing();
        let hop = bump(TAU * 1.4 * t + j.phase, 2);
        p.legs[1] = Leg { hip_flex: d(35.0), knee: d(80.0), ..Leg::default() };
        p.legs[0].knee = j.amp * d(30.0) * (1.0 - hop);
        p.legs[0].hip_flex = j.amp * d(20.0) * (1.0 - hop);
        p.legs[0].ankle = d(20.0) * hop - d(10.0) * (1.0 - hop);
        p.lift = 0.09 * j.amp * hop;
        for a in &mut p.arms { a.abd = d(0.0) + d(15.0) * hop; a.elbow = d(40.0); }
        p
    };
    "squat_jump", 7.0, |t, j| {
        let mut p = jump(t, j, 2.2, 0.3, 0.0, 0.0);
        let (c, _) = jump_phase(t, 2.2);
        crouch_legs(&mut p, c, 1.25 * j.amp);
        p
    };
    // Lower body.
    "squat_shallow", 7.0, |t, j| squat(t, j, 0.55, 0.4);
    "squat_deep", 8.0, |t, j| squat(t, j, 1.05, 0.3);
    "lunge_left", 8.0, |t, j| lunge(t, j, 0.3, false);
    "lunge_alternating", 8.0, |t, j| lunge(t, j, 0.3, true);
    "kick_front_left", 6.0, |t, j| kick(t, j, 0, 1.5, true);
    "kick_front_right", 6.0, |t, j| kick(t, j, 1, 1.4, true);
    "kick_side_right", 6.0, |t, j| kick(t, j, 1, 1.6, false);
    "knee_raise_alternating", 8.0, |t, j| step_in_place(t, 0.55, d(95.0), d(100.0), j);
    "leg_swing_left", 6.0, |t, j| {
        let mut p = standing();
        p.legs[0].hip_flex = j.amp * d(45.0) * sw(t, 0.8, j.phase) + d(10.0);
        p.legs[0].knee = d(10.0) + d(15.0) * bump(TAU * 0.8 * t + j.phase - PI / 2.0, 2);
        p.legs[1].knee = d(8.0);
        for a in &mut p.arms { a.abd = d(40.0); a.elbow = d(15.0); }
        p
    };
    "calf_raises", 6.0, |t, j| {
        let mut p = standing();
        let w = bump(TAU * 0.7 * t + j.phase + PI, 2);
        for l in &mut p.legs { l.ankle = j.amp * d(30.0) * w; l.toe = j.amp * d(30.0) * w; }
        p.lift = 0.1 * (j.amp * d(30.0) * w).sin();
        p
    };
    // Upper body: reaches.
    "reach_up_both", 7.0, |t, j| {
        let up = Arm { abd: d(120.0), clav_elev: d(15.0), elbow: d(5.0), ..Arm::default() };
        reach(t, j, 0.35, [Some(up), Some(up)], [d(-8.0), 0.0, 0.0], d(20.0))
    };
    "reach_up_left", 7.0, |t, j| {
        let up = Arm { abd: d(118.0), clav_elev: d(18.0), elbow: d(5.0), ..Arm::default() };
        reach(t, j, 0.4, [Some(up), None], [0.0, d(-14.0), 0.0], d(15.0))
    };
    "reach_forward_both", 7.0, |t, j| {
        let fwd = Arm { abd: d(45.0), horiz: d(85.0), clav_fwd: d(12.0), elbow: d(2.0), ..Arm::default() };
        reach(t, j, 0.4, [Some(fwd), Some(fwd)], [d(25.0), 0.0, 0.0], 0.0)
    };
    "reach_forward_right", 7.0, |t, j| {
        let fwd = Arm { abd: d(40.0), horiz: d(90.0), clav_fwd: d(15.0), elbow: d(2.0), ..Arm::default() };
        reach(t, j, 0.45, [None, Some(fwd)], [d(20.0), 0.0, d(-20.0)], 0.0)
    };
    "reach_side_left", 7.0, |t, j| {
        let side = Arm { abd: d(50.0), clav_elev: d(8.0), elbow: d(2.0), ..Arm::default() };
        reach(t, j, 0.4, [Some(side), None], [0.0, d(22.0), 0.0], 0.0)
    };
    "reach_side_both", 7.0, |t, j| {
        let side = Arm { abd: d(48.0), elbow: d(2.0), twist: d(20.0), ..Arm::default() };
        reach(t, j, 0.5, [Some(side), Some(side)], [d(-5.0), 0.0, 0.0], d(10.0))
    };
    // Upper body: swings and circles.
    "arm_swing_small", 6.0, |t, j| arm_swing(t, j, 0.8, 20.0, [true, true], true);
    "arm_swing_large", 7.0, |t, j| arm_swing(t, j, 0.6, 65.0, [true, true], true);
    "arm_swing_fast", 6.0, |t, j| arm_swing(t, j, 2.0, 45.0, [true, true], true);
    "arm_swing_left", 6.0, |t, j| arm_swing(t, j, 0.9, 55.0, [true, false], false);
    "arm_swing_parallel", 6.0, |t, j| arm_swing(t, j, 0.7, 50.0, [true, true], false);
    "arm_circles_small", 6.0, |t, j| arm_circles(t, j, 1.2, 15.0, [true, true], 1.0);
    "arm_circles_large", 7.0, |t, j| arm_circles(t, j, 0.6, 50.0, [true, true], 1.0);
    "arm_circles_fast", 6.0, |t, j| arm_circles(t, j, 2.2, 30.0, [true, true], 1.0);
    "arm_circles_left", 6.0, |t, j| arm_circles(t, j, 0.8, 45.0, [true, false], 1.0);
    "arm_circles_backward", 6.0, |t, j| arm_circles(t, j, 0.9, 35.0, [true, true], -1.0);
    "arm_flap", 6.0, |t, j| {
        let mut p = standing();
        let w = bump(TAU * 1.3 * t + j.phase + PI, 2);
        for a in &mut p.arms { a.abd = d(-30.0) + j.amp * d(110.0) * w; a.elbow = d(8.0); }
        p
    };
    "wave_left", 6.0, |t, j| {
        let mut p = standing();
        p.arms[0] = Arm { abd: d(100.0), clav_elev: d(10.0), elbow: d(75.0), twist: j.amp * d(30.0) * sw(t, 1.8, j.phase), wrist: d(10.0) * sw(t, 1.8, j.phase + 1.0), ..Arm::default() };
        p.neck[1] = d(6.0);
        p
    };
    "punch_alternating", 7.0, |t, j| {
        let mut p = standing();
        for side in 0..2 {
            let u = t / 0.9 + if side == 1 { 0.5 } else { 0.0 } + j.phase / TAU;
            let strike = beat(u, 1.0, 0.0, 0.45);
            p.arms[side] = Arm { abd: d(25.0) + d(15.0) * strike, horiz: d(70.0) + d(15.0) * strike, elbow: d(125.0) * (1.0 - 0.9 * strike * j.amp.min(1.0)), flex: d(10.0) * strike, clav_fwd: d(12.0) * strike, ..Arm::default() };
            p.spine[2] += if side == 0 { -1.0 } else { 1.0 } * d(18.0) * strike;
        }
        for l in &mut p.legs { l.knee = d(15.0); l.hip_flex = d(8.0); }
        p
    };
    "clap_front", 6.0, |t, j| {
        let mut p = standing();
        let c = bump(TAU * 1.5 * t + j.phase, 2);
        for a in &mut p.arms { *a = Arm { abd: d(35.0), horiz: d(40.0) + j.amp * d(45.0) * c, elbow: d(35.0), ..Arm::default() }; }
        p
    };
    "shrug", 6.0, |t, j| {
        let mut p = standing();
        let w = bump(TAU * 0.6 * t + j.phase + PI, 2);
        for a in &mut p.arms { a.clav_elev = j.amp * d(22.0) * w; }
        p.neck[0] = -d(5.0) * w;
        p
    };
    // Torso.
    "torso_twist", 7.0, |t, j| twist(t, j, 0.45, 50.0);
    "torso_twist_fast", 6.0, |t, j| twist(t, j, 1.2, 35.0);
    "bend_forward", 7.0, |t, j| {
        let mut p = standing();
        let w = j.amp * bump(TAU * 0.3 * t + j.phase + PI, 2);
        p.pelvis[0] = d(35.0) * w;
        p.spine[0] = d(45.0) * w;
        p.neck[0] = d(10.0) * w;
        for l in &mut p.legs { l.hip_flex = d(35.0) * w; }
        for a in &mut p.arms { a.flex = d(60.0) * w; }
        p
    };
    "bend_side", 7.0, |t, j| {
        let mut p = standing();
        let s = j.amp * sw(t, 0.35, j.phase);
        p.spine[1] = d(40.0) * s;
        p.pelvis[1] = -d(6.0) * s;
        p.neck[1] = d(10.0) * s;
        p.arms[0].abd = d(-38.0) + d(120.0) * s.max(0.0).powi(2);
        p.arms[1].abd = d(-38.0) + d(120.0) * (-s).max(0.0).powi(2);
        p
    };
    "hip_circles", 6.0, |t, j| {
        let mut p = standing();
        let ph = TAU * 0.6 * t + j.phase;
        p.pelvis = [j.amp * d(10.0) * ph.sin(), j.amp * d(10.0) * ph.cos(), 0.0];
        p.spine = [-j.amp * d(8.0) * ph.sin(), j.amp * d(8.0) * ph.cos(), 0.0];
        for l in &mut p.legs { l.knee = d(12.0); l.hip_flex = d(6.0); }
        for a in &mut p.arms { a.abd = d(-20.0); a.elbow = d(80.0); a.horiz = d(20.0); }
        p
    };
    "toe_touch", 8.0, |t, j| {
        let mut p = standing();
        let w = j.amp * bump(TAU * 0.25 * t + j.phase + PI, 2);
        p.pelvis[0] = d(55.0) * w;
        p.spine[0] = d(60.0) * w;
        p.neck[0] = d(20.0) * w;
        for l in &mut p.legs { l.hip_flex = d(55.0) * w; l.knee = d(8.0) * w; }
        for a in &mut p.arms { a.flex = d(95.0) * w; a.elbow = d(5.0); }
        p
    };
    "stretch_overhead", 8.0, |t, j| {
        let up = Arm { abd: d(125.0), clav_elev: d(15.0), elbow: d(3.0), twist: d(30.0), ..Arm::default() };
        let mut p = reach(t, j, 0.2, [Some(up), Some(up)], [d(-10.0), 0.0, 0.0], d(15.0));
        p.spine[1] = d(20.0) * sw(t, 0.4, j.phase) * bump(TAU * 0.2 * t + PI, 2);
        p
    };
    // Turns.
    "turn_in_place_left", 8.0, |t, j| Params { turn_rate: 1.1, ..step_in_place(t, 1.0, d(30.0), d(45.0), j) };
    "turn_in_place_right", 8.0, |t, j| Params { turn_rate: -1.1, ..step_in_place(t, 1.0, d(30.0), d(45.0), j) };
    "spin", 6.0, |t, j| {
        let mut p = step_in_place(t, 1.6, d(25.0), d(40.0), j);
        p.turn_rate = 4.0 * j.amp;
        for a in &mut p.arms { a.abd = d(55.0); a.elbow = d(60.0); a.horiz = d(40.0); }
        p.spine[2] = d(10.0);
        p
    };
    // Dance.
    "dance_sway", 8.0, |t, j| {
        let mut p = dance_base(t, j, 0.5, 15.0);
        let s = sw(t, 0.5, j.phase);
        p.pelvis[1] = j.amp * d(10.0) * s;
        p.spine[1] = -j.amp * d(12.0) * s;
        p.left_speed = 0.25 * j.amp * cw(t, 0.5, j.phase);
        for (side, a) in p.arms.iter_mut().enumerate() {
            let k = if side == 0 { 1.0 } else { -1.0 };
            a.abd = d(10.0) + k * d(35.0) * s;
            a.elbow = d(50.0);
        }
        p
    };
    "dance_disco", 8.0, |t, j| {
        let mut p = dance_base(t, j, 1.0, 20.0);
        let up = bump(TAU * 1.0 * t + j.phase, 2);
        p.arms[1] = Arm { abd: j.amp * (d(-20.0) + d(140.0) * up), horiz: d(55.0) * (1.0 - up), elbow: d(10.0), clav_elev: d(12.0) * up, ..Arm::default() };
        p.arms[0] = Arm { abd: d(-20.0), elbow: d(95.0), horiz: d(30.0), ..Arm::default() };
        p.pelvis[1] = j.amp * d(10.0) * sw(t, 1.0, j.phase);
        p.spine[2] = j.amp * d(15.0) * sw(t, 1.0, j.phase + 0.5);
        p.neck[2] = -d(20.0) * up + d(10.0);
        p
    };
    "dance_bounce", 8.0, |t, j| {
        let mut p = dance_base(t, j, 1.0, 25.0);
        for (side, a) in p.arms.iter_mut().enumerate() {
            let ph = j.phase + if side == 0 { 0.0 } else { PI };
            *a = Arm { abd: d(-10.0), elbow: d(90.0), flex: j.amp * d(35.0) * sw(t, 1.0, ph), ..Arm::default() };
        }
        p.spine[0] = d(8.0);
        p
    };
    "dance_twist", 8.0, |t, j| {
        let mut p = dance_base(t, j, 0.0, 0.0);
        let s = sw(t, 1.4, j.phase);
        p.pelvis[2] = j.amp * d(30.0) * s;
        p.spine[2] = -j.amp * d(40.0) * s;
        for l in &mut p.legs { l.knee = d(35.0); l.hip_flex = d(20.0); l.ankle = -d(12.0); l.hip_rot = d(10.0) * s; }
        for a in &mut p.arms { a.abd = d(15.0); a.elbow = d(85.0); a.horiz = d(20.0); }
        p
    };
    "dance_hiphop", 8.0, |t, j| {
        let mut p = dance_base(t, j, 1.1, 30.0);
        let step = sw(t, 0.55, j.phase);
        p.left_speed = 0.35 * j.amp * cw(t, 0.55, j.phase);
        p.legs[0].hip_abd = d(10.0) * step.max(0.0);
        p.legs[1].hip_abd = d(10.0) * (-step).max(0.0);
        for (side, a) in p.arms.iter_mut().enumerate() {
            let pump = bump(TAU * 1.1 * t + j.phase + side as f64 * PI, 2);
            *a = Arm { abd: d(-10.0) + d(60.0) * pump, elbow: d(100.0) - d(60.0) * pump, horiz: d(25.0), ..Arm::default() };
        }
        p.neck[0] = d(12.0) * bump(TAU * 2.2 * t + j.phase, 2);
        p.spine[0] = d(10.0);
        p
    };
    "dance_salsa", 8.0, |t, j| {
        let mut p = standing();
        for side in 0..2 {
            let phi = TAU * 0.75 * t + j.phase + side as f64 * PI;
            p.legs[side].hip_flex = j.amp * d(22.0) * phi.sin();
            p.legs[side].knee = j.amp * d(30.0) * bump(phi, 2);
            p.arms[side] = Arm { abd: d(25.0), elbow: d(80.0), horiz: d(30.0), flex: d(15.0) * phi.cos(), ..Arm::default() };
        }
        let base = TAU * 0.75 * t + j.phase;
        p.forward_speed = 0.25 * base.cos();
        p.pelvis = [0.0, j.amp * d(12.0) * (2.0 * base).sin(), j.amp * d(10.0) * base.sin()];
        p.spine = [0.0, -j.amp * d(8.0) * (2.0 * base).sin(), -j.amp * d(15.0) * base.sin()];
        p
    };
    "dance_arm_wave", 7.0, |t, j| {
        let mut p = dance_base(t, j, 0.6, 10.0);
        for (side, a) in p.arms.iter_mut().enumerate() {
            let ph = TAU * 0.8 * t + j.phase - side as f64 * 1.2;
            *a = Arm { abd: d(45.0) + j.amp * d(25.0) * ph.sin(), elbow: d(30.0) + d(30.0) * bump(ph - 0.8, 2), wrist: d(25.0) * (ph - 1.6).sin(), clav_elev: d(6.0) * ph.sin(), ..Arm::default() };
        }
        p
    };
    // Idle.
    "idle", 6.0, |t, j| {
        let mut p = standing();
        let b = sw(t, 0.25, j.phase);
        p.spine[0] = d(2.0) * b;
        p.arms[0].clav_elev = d(2.0) * (b + 1.0);
        p.arms[1].clav_elev = d(2.0) * (b + 1.0);
        p.pelvis[1] = d(3.0) * sw(t, 0.12, j.phase);
        p.legs[0].knee = d(4.0) * (1.0 + sw(t, 0.12, j.phase));
        p.neck[2] = d(12.0) * sw(t, 0.1, j.phase + 1.0);
        p
    };
}

fn side_step(t: f64, j: &Jitter, dir: f64) -> Params {
    let mut p = standing();
    let hz = 0.8;
    let phi = TAU * hz * t + j.phase;
    // The leading leg opens, the trailing leg closes.
    let lead = if dir > 0.0 { 0 } else { 1 };
    p.legs[lead].hip_abd = j.amp * d(20.0) * bump(phi, 2);
    p.legs[lead].knee = d(15.0) * bump(phi + 0.6, 2);
    p.legs[1 - lead].hip_abd = j.amp * d(14.0) * bump(phi - PI * 0.9, 2);
    p.legs[1 - lead].knee = d(15.0) * bump(phi - PI * 0.9 + 0.6, 2);
    p.left_speed = dir * 0.45 * j.amp * (0.6 + 0.4 * phi.cos());
    for a in &mut p.arms {
        a.abd = d(-30.0) + d(20.0) * bump(phi, 2);
        a.elbow = d(20.0);
    }
    p
}

fn squat(t: f64, j: &Jitter, depth: f64, hz: f64) -> Params {
    let mut p = standing();
    let w = j.amp * depth * bump(TAU * hz * t + j.phase + PI, 2);
    for l in &mut p.legs {
        l.hip_flex = d(95.0) * w;
        l.knee = d(115.0) * w;
        l.ankle = -d(28.0) * w;
        l.hip_abd = d(8.0) * w;
        l.hip_rot = d(12.0) * w;
    }
    p.pelvis[0] = d(10.0) * w;
    p.spine[0] = d(25.0) * w;
    p.neck[0] = -d(15.0) * w;
    for a in &mut p.arms {
        a.abd = d(-38.0) + d(83.0) * w;
        a.horiz = d(85.0) * w;
        a.elbow = d(12.0) - d(8.0) * w;
    }
    p
}

fn lunge(t: f64, j: &Jitter, hz: f64, alternate: bool) -> Params {
    let mut p = standing();
    let ph = TAU * hz * t + j.phase;
    let (w, front) = if alternate {
        let s = ph.sin();
        (s.abs().powi(2) * j.amp, if s >= 0.0 { 0 } else { 1 })
    } else {
        (bump(ph + PI, 2) * j.amp, 0)
    };
    let back = 1 - front;
    p.legs[front].hip_flex = d(75.0) * w;
    p.legs[front].knee = d(90.0) * w;
    p.legs[front].ankle = -d(15.0) * w;
    p.legs[back].hip_flex = -d(20.0) * w;
    p.legs[back].knee = d(85.0) * w;
    p.legs[back].ankle = d(35.0) * w;
    p.legs[back].toe = d(35.0) * w;
    p.spine[0] = -d(5.0) * w;
    for a in &mut p.arms {
        a.abd = d(-38.0) + d(20.0) * w;
        a.elbow = d(12.0) + d(60.0) * w;
    }
    p
}
