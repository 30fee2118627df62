//! The built-in body's skeleton: the 31 bones of MakeHuman's `cmu_mb` rig, named like the CMU
//! motion-capture BVH files, in an order where every parent precedes its children.

/// `(joint name, parent name)` in skeleton order. Joint 0 is the root.
pub const CMU_MB_JOINTS: [(&str, Option<&str>); 31] = [
    ("Hips", None),
    ("LHipJoint", Some("Hips")),
    ("LeftUpLeg", Some("LHipJoint")),
    ("LeftLeg", Some("LeftUpLeg")),
    ("LeftFoot", Some("LeftLeg")),
    ("LeftToeBase", Some("LeftFoot")),
    ("RHipJoint", Some("Hips")),
    ("RightUpLeg", Some("RHipJoint")),
    ("RightLeg", Some("RightUpLeg")),
    ("RightFoot", Some("RightLeg")),
    ("RightToeBase", Some("RightFoot")),
    ("LowerBack", Some("Hips")),
    ("Spine", Some("LowerBack")),
    ("Spine1", Some("Spine")),
    ("Neck", Some("Spine1")),
    ("Neck1", Some("Neck")),
    ("Head", Some("Neck1")),
    ("LeftShoulder", Some("Spine1")),
    ("LeftArm", Some("LeftShoulder")),
    ("LeftForeArm", Some("LeftArm")),
    ("LeftHand", Some("LeftForeArm")),
    ("LeftFingerBase", Some("LeftHand")),
    ("LeftHandFinger1", Some("LeftFingerBase")),
    ("LThumb", Some("LeftHand")),
    ("RightShoulder", Some("Spine1")),
    ("RightArm", Some("RightShoulder")),
    ("RightForeArm", Some("RightArm")),
    ("RightHand", Some("RightForeArm")),
    ("RightFingerBase", Some("RightHand")),
    ("RightHandFinger1", Some("RightFingerBase")),
    ("RThumb", Some("RightHand")),
];

/// The 20 body joints of [`CMU_MB_JOINTS`] without fingers, thumbs, hip joints, toes and the
/// second neck joint: the pose a garment network of the benchmarks and test scenes sees (a
/// dataset selects its own from the garment's skin weights).
pub fn cmu_mb_body_joints() -> Vec<String> {
    const LEFT_OUT: [&str; 5] = ["Finger", "Thumb", "HipJoint", "ToeBase", "Neck1"];
    CMU_MB_JOINTS
        .iter()
        .map(|j| j.0)
        .filter(|n| !LEFT_OUT.iter().any(|e| n.contains(e)))
        .map(String::from)
        .collect()
}

/// The `cmu_mb` skeleton as a [`sartor_core::Skeleton`].
pub fn cmu_mb_skeleton() -> sartor_core::Skeleton {
    let names: Vec<String> = CMU_MB_JOINTS.iter().map(|(n, _)| n.to_string()).collect();
    let parents = CMU_MB_JOINTS
        .iter()
        .map(|(_, p)| {
            p.map(|p| {
                CMU_MB_JOINTS
                    .iter()
                    .position(|(n, _)| *n == p)
                    .expect("parents are listed in CMU_MB_JOINTS")
            })
        })
        .collect();
    sartor_core::Skeleton::new(names, parents)
        .expect("CMU_MB_JOINTS lists parents before children, names unique")
}

#[cfg(test)]
mod tests {
    #[test]
    fn skeleton_is_valid() {
        let s = super::cmu_mb_skeleton();
        assert_eq!(s.n_joints(), 31);
        assert_eq!(
            s.parents()[s.index_of("LeftArm").expect("exists")],
            s.index_of("LeftShoulder")
        );
    }
}
