//! Which rig joint each joint of a BVH file drives: [`map_bvh_joints`].

use std::cmp::Reverse;

use nalgebra::Vector3;
use serde::Serialize;

use crate::bvh::{Bvh, cmu_to_rig_name};
use crate::rig::CMU_MB_JOINTS;

/// How [`map_bvh_joints`] matched a file's joints to the rig's.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BvhJointMatch {
    /// Every joint by its name (CMU's naming, see [`cmu_to_rig_name`]).
    Names,
    /// By the skeleton's structure (see [`map_bvh_joints`]).
    Structure,
}

/// Per joint of a BVH file, the rig joint it drives ([`map_bvh_joints`]).
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct BvhJointMap {
    /// How the joints were matched.
    pub matched_by: BvhJointMatch,
    /// Per joint of the file (file order), the rig joint's name (`None`: it drives none).
    pub rig_joints: Vec<Option<&'static str>>,
}

impl BvhJointMap {
    /// No joint of `bvh` drives a rig joint.
    pub(crate) fn none(bvh: &Bvh) -> Self {
        Self {
            matched_by: BvhJointMatch::Names,
            rig_joints: vec![None; bvh.joints().len()],
        }
    }

    /// The file joint that drives rig joint `name`.
    pub fn file_joint(&self, name: &str) -> Option<usize> {
        self.rig_joints.iter().position(|r| *r == Some(name))
    }

    /// Every joint of `bvh` by the name of the rig joint of its name (CMU's naming; `None`
    /// where the rig has none).
    pub(crate) fn by_name(bvh: &Bvh) -> Self {
        Self {
            matched_by: BvhJointMatch::Names,
            rig_joints: bvh
                .joints()
                .iter()
                .map(|j| rig_name(cmu_to_rig_name(&j.name)))
                .collect(),
        }
    }

    /// `[file joint, rig joint]` for every joint of `bvh` that drives one, and the names of
    /// those that drive none, in file order.
    pub fn pairs(&self, bvh: &Bvh) -> (Vec<[String; 2]>, Vec<String>) {
        let (mut pairs, mut unused) = (Vec::new(), Vec::new());
        for (joint, rig) in bvh.joints().iter().zip(&self.rig_joints) {
            match rig {
                Some(r) => pairs.push([joint.name.clone(), r.to_string()]),
                None => unused.push(joint.name.clone()),
            }
        }
        (pairs, unused)
    }

    /// Per joint of the file, the rig joint's name where it drives one, else its own name.
    pub(crate) fn names(&self, bvh: &Bvh) -> Vec<String> {
        self.rig_joints
            .iter()
            .zip(bvh.joints())
            .map(|(r, j)| r.map_or_else(|| j.name.clone(), str::to_string))
            .collect()
    }
}

/// The rig's joint named `name` as a static name (`None`: the rig has none).
fn rig_name(name: &str) -> Option<&'static str> {
    CMU_MB_JOINTS.iter().map(|(n, _)| *n).find(|n| *n == name)
}

/// Match the joints of `bvh` to the rig's. `Err` says why the structure was not understood.
///
/// CMU's files name their joints as the rig does ([`crate::CMU_MB_JOINTS`]); every joint of such
/// a file drives the rig joint of its name ([`BvhJointMatch::Names`]). Files from other tools
/// name and divide the same body differently: Mixamo (`mixamorig:LeftArm`, three spine joints),
/// Biovision and MocapBank (`LeftCollar`, `LeftShoulder` for the *upper arm*, `LeftElbow`,
/// `LeftHip` for the thigh, `Chest`, `Chest2`), Blender's Rigify (`upper_arm.L`, `thigh.R`, the
/// thighs on the root beside `pelvis.L`), LAFAN1 (`Spine2`, `LeftToe`), DAZ and Poser (`lShldr`,
/// `lThigh`, `abdomen`), 3ds Max Biped (`Bip01 L UpperArm`), SMPL's BVH exports (`L_Collar`,
/// `L_Shoulder` for the upper arm, `Spine3`). Names are no guide across these —
/// `LeftShoulder` is the collar in one and the upper arm in another — so any other file is
/// matched by its structure ([`BvhJointMatch::Structure`]), with the names used only to tell left
/// from right:
///
/// - the **hips** are the root, or the first joint below it with more than one child (a file
///   may hang its skeleton under a static reference node);
/// - the **spine** is the hips' child with the largest subtree, followed (child with the
///   largest subtree, the first on ties) up to the **chest**, the first joint with three or more
///   children; the chest drives `Spine1`, the spine's first joint `LowerBack` and the one before
///   the chest `Spine` (a shorter spine leaves them to follow their parent);
/// - the **legs** are the two other children of the hips with the longest chains (a chain: the
///   child with the largest subtree, down to a leaf; its length the sum of its bones, an end
///   site's included); the **arms** the two children of the chest with the longest chains other
///   than the **neck** (the child named `neck` or `head`, else the one whose chain ends most in
///   line with the spine);
/// - along a leg's chain the two longest consecutive bones are the thigh and shin: their joints
///   drive `LeftUpLeg` and `LeftLeg`, the next two joints `LeftFoot` and `LeftToeBase`, the joint
///   before the thigh `LHipJoint`;
/// - along an arm's chain the hand is the first joint with fingers (two or more children, none
///   starting far from it: a forearm's twist bone does not make it a hand);
///   without fingers, the forearm is the start of the last long bone (the hand's are short). A
///   collar can be longer than a forearm (CMU subject 02's is 3.66 against 3.36 units, subject
///   05's forearm is 0.45 of its upper arm), so the longest bones do not find an arm. The hand
///   drives `LeftHand`, the two joints before it `LeftArm` and `LeftForeArm`, the one before
///   those `LeftShoulder`;
/// - along the neck's chain the first joint named `head` (else the chain's last joint, when it
///   has two or more) drives `Head`, the first two joints before it `Neck` and `Neck1`;
/// - left and right from the names' words (`Left…`, `…_L`, `.L`, `l` in `lShldr`, `L` in
///   `Bip01 L Thigh`), else from the rest pose: the left leg lies on the side of `up × forward`,
///   with up from the root to the chest and forward from the ankles to the toes.
///
/// Joints matched to nothing (fingers, eyes, end joints, Rigify's `pelvis.L`) drive nothing;
/// their rotations still reach the joints below them. The retarget and its check then work as
/// for CMU's files: [`crate::check_bvh_retarget`] compares every matched bone with the file's own
/// forward kinematics.
pub fn map_bvh_joints(bvh: &Bvh) -> Result<BvhJointMap, String> {
    let by_name = BvhJointMap::by_name(bvh);
    if by_name.rig_joints.iter().all(Option::is_some) {
        return Ok(by_name);
    }
    map_bvh_joints_by_structure(bvh)
}

/// [`map_bvh_joints`]'s match by structure, whatever the names (see [`map_bvh_joints`]).
pub fn map_bvh_joints_by_structure(bvh: &Bvh) -> Result<BvhJointMap, String> {
    Ok(BvhJointMap {
        matched_by: BvhJointMatch::Structure,
        rig_joints: Structure::new(bvh).map()?,
    })
}

/// Along an arm, a bone at least this share of the chain's longest is the upper arm, the
/// forearm or the collar; the hand's and fingers' are shorter (MocapBank's wrist's end site:
/// 0.55 of its upper arm, Mixamo's hand to middle finger about 0.35; Rigify's forearm ends in
/// an end site, 0.87 of the upper arm).
const LONG_SHARE: f64 = 0.6;

/// A side of the body.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Side {
    Left,
    Right,
}

/// The side a joint's name says (`None`: neither, or both).
fn side_of(name: &str) -> Option<Side> {
    let words = words(name);
    let has = |w: &[&str]| words.iter().any(|x| w.contains(&x.as_str()));
    match (
        has(&["left", "l", "lft"]),
        has(&["right", "r", "rt", "rgt"]),
    ) {
        (true, false) => Some(Side::Left),
        (false, true) => Some(Side::Right),
        _ => None,
    }
}

/// Whether a joint's name holds the word `word`.
fn names_word(name: &str, word: &str) -> bool {
    words(name).iter().any(|w| w == word)
}

/// The lower-case words of a joint name: split at every character that is not a letter or
/// digit, between a lower-case letter and an upper-case one (`LeftArm`), before the last
/// capital of a run that a lower-case letter follows (`LHip` → `l`, `hip`), and between
/// letters and digits (`Bip01`).
fn words(name: &str) -> Vec<String> {
    let chars: Vec<char> = name.chars().collect();
    let mut out = Vec::new();
    let mut word = String::new();
    for (k, &c) in chars.iter().enumerate() {
        if !c.is_alphanumeric() {
            if !word.is_empty() {
                out.push(std::mem::take(&mut word));
            }
            continue;
        }
        if let Some(&p) = k.checked_sub(1).map(|k| &chars[k]) {
            let next_lower = chars.get(k + 1).is_some_and(|n| n.is_lowercase());
            let split = (p.is_lowercase() && c.is_uppercase())
                || (p.is_uppercase() && c.is_uppercase() && next_lower)
                || (p.is_alphabetic() != c.is_alphabetic() && p.is_alphanumeric());
            if split && !word.is_empty() {
                out.push(std::mem::take(&mut word));
            }
        }
        word.extend(c.to_lowercase());
    }
    if !word.is_empty() {
        out.push(word);
    }
    out
}

/// A BVH skeleton's tree, for [`map_bvh_joints`]'s structural match.
struct Structure<'a> {
    bvh: &'a Bvh,
    children: Vec<Vec<usize>>,
    size: Vec<usize>,
    rest: Vec<Vector3<f64>>,
}

/// Joints along one limb or the spine, and the rig joints they drive.
type Chain = Vec<usize>;

impl<'a> Structure<'a> {
    fn new(bvh: &'a Bvh) -> Self {
        let n = bvh.joints().len();
        let mut children = vec![Vec::new(); n];
        let mut size = vec![1; n];
        for (j, joint) in bvh.joints().iter().enumerate() {
            if let Some(p) = joint.parent {
                children[p].push(j);
            }
        }
        // Parents precede their children in a BVH file.
        for j in (0..n).rev() {
            if let Some(p) = bvh.joints()[j].parent {
                size[p] += size[j];
            }
        }
        Self {
            bvh,
            children,
            size,
            rest: bvh.rest_positions(),
        }
    }

    /// The child of `j` with the largest subtree (the first on ties).
    fn main_child(&self, j: usize) -> Option<usize> {
        self.children[j]
            .iter()
            .copied()
            .max_by_key(|&c| (self.size[c], Reverse(c)))
    }

    /// The chain from `j`: `j`, then its main child, down to a leaf.
    fn chain(&self, j: usize) -> Chain {
        let mut chain = vec![j];
        let mut at = j;
        while let Some(c) = self.main_child(at) {
            chain.push(c);
            at = c;
        }
        chain
    }

    /// The bone from `chain[i]`: to the next joint of the chain, or to its end site (zero
    /// without one).
    fn bone(&self, chain: &[usize], i: usize) -> f64 {
        match chain.get(i + 1) {
            Some(&c) => self.bvh.joints()[c].offset.norm(),
            None => self.bvh.joints()[chain[i]]
                .end_site
                .map_or(0.0, |e| e.norm()),
        }
    }

    fn length(&self, chain: &[usize]) -> f64 {
        (0..chain.len()).map(|i| self.bone(chain, i)).sum()
    }

    /// Where along `chain` its two longest consecutive bones start (both joints in the chain).
    fn limb_start(&self, chain: &[usize]) -> Option<usize> {
        (0..chain.len().saturating_sub(1)).max_by(|&a, &b| {
            let pair = |i| self.bone(chain, i) + self.bone(chain, i + 1);
            pair(a).total_cmp(&pair(b)).then(b.cmp(&a))
        })
    }

    /// The two longest chains from the children of `j` other than `besides`, longest first
    /// (the first on ties).
    fn two_longest(&self, j: usize, besides: usize) -> Option<[Chain; 2]> {
        let mut chains: Vec<Chain> = self.children[j]
            .iter()
            .filter(|&&c| c != besides)
            .map(|&c| self.chain(c))
            .collect();
        // Stable: equal lengths keep file order.
        chains.sort_by(|a, b| self.length(b).total_cmp(&self.length(a)));
        let mut it = chains.into_iter();
        Some([it.next()?, it.next()?])
    }

    fn name(&self, j: usize) -> &str {
        &self.bvh.joints()[j].name
    }

    /// The mean rest position of `chain`'s joints.
    fn centre(&self, chain: &[usize]) -> Vector3<f64> {
        chain.iter().map(|&j| self.rest[j]).sum::<Vector3<f64>>() / chain.len() as f64
    }

    /// `[left, right]` of a pair of chains: by their first joints' names, else by `lateral`
    /// (the body's left, in the rest pose) and their joints' mean positions.
    fn sides(&self, pair: [Chain; 2], lateral: Option<Vector3<f64>>) -> Option<[Chain; 2]> {
        let named = pair.each_ref().map(|c| side_of(self.name(c[0])));
        let left_first = match named {
            [Some(Side::Left), Some(Side::Right)] => true,
            [Some(Side::Right), Some(Side::Left)] => false,
            _ => {
                let d = self.centre(&pair[0]) - self.centre(&pair[1]);
                let along = d.dot(&lateral?);
                if along == 0.0 || !along.is_finite() {
                    return None;
                }
                along > 0.0
            }
        };
        let [a, b] = pair;
        Some(if left_first { [a, b] } else { [b, a] })
    }

    /// The rig joint each file joint drives (see [`map_bvh_joints`]).
    fn map(&self) -> Result<Vec<Option<&'static str>>, String> {
        let n = self.bvh.joints().len();
        // The hips: the root, or below a chain of single children (a reference node).
        let mut root = 0;
        while let [only] = self.children[root][..] {
            root = only;
        }
        let spine_start = self
            .main_child(root)
            .ok_or("the root has no children: no spine or legs")?;
        let mut spine = vec![spine_start];
        let mut chest = spine_start;
        while self.children[chest].len() < 3 {
            chest = self.main_child(chest).ok_or(
                "no joint along the spine (the root's largest branch) carries two arms and a neck",
            )?;
            spine.push(chest);
        }
        let legs = self
            .two_longest(root, spine_start)
            .ok_or("the root has fewer than two branches besides the spine: no two legs")?;
        let up = self.rest[chest] - self.rest[root];
        // Joints above the hips (a reference node) drive nothing; their motion reaches the hips.
        let neck = self.children[chest]
            .iter()
            .copied()
            .find(|&c| names_word(self.name(c), "neck") || names_word(self.name(c), "head"))
            .or_else(|| {
                // The child whose chain ends most in line with the spine (joints may start
                // where the chest is: CMU's do).
                self.children[chest].iter().copied().max_by(|&a, &b| {
                    let along = |c: usize| {
                        let end = *self.chain(c).last().expect("a chain holds its start");
                        let d = self.rest[end] - self.rest[chest];
                        let along = d.dot(&up) / (d.norm() * up.norm());
                        if along.is_finite() {
                            along
                        } else {
                            f64::NEG_INFINITY
                        }
                    };
                    along(a).total_cmp(&along(b)).then(b.cmp(&a))
                })
            })
            .ok_or("the chest has no neck")?;
        let arms = self
            .two_longest(chest, neck)
            .ok_or("the chest carries fewer than two arms")?;
        // The body's left in the rest pose, for chains whose names do not tell: from the legs'
        // names, else from up × forward (the ankle-to-toe direction).
        let lateral = match self.sides(legs.clone(), None) {
            Some([l, r]) => Some(self.centre(&l) - self.centre(&r)),
            None => self.lateral_from_feet(&legs, &up),
        };
        let [left_leg, right_leg] = self
            .sides(legs, lateral)
            .ok_or("cannot tell the left leg from the right: neither names nor feet say")?;
        let [left_arm, right_arm] = self
            .sides(arms, lateral)
            .ok_or("cannot tell the left arm from the right")?;

        let mut rig: Vec<Option<&'static str>> = vec![None; n];
        rig[root] = Some("Hips");
        let m = spine.len();
        rig[chest] = Some("Spine1");
        if m >= 2 {
            rig[spine[0]] = Some("LowerBack");
        }
        if m >= 3 {
            rig[spine[m - 2]] = Some("Spine");
        }
        let legs = [
            (
                left_leg,
                [
                    "LHipJoint",
                    "LeftUpLeg",
                    "LeftLeg",
                    "LeftFoot",
                    "LeftToeBase",
                ],
            ),
            (
                right_leg,
                [
                    "RHipJoint",
                    "RightUpLeg",
                    "RightLeg",
                    "RightFoot",
                    "RightToeBase",
                ],
            ),
        ];
        let arms = [
            (
                left_arm,
                ["LeftShoulder", "LeftArm", "LeftForeArm", "LeftHand"],
            ),
            (
                right_arm,
                ["RightShoulder", "RightArm", "RightForeArm", "RightHand"],
            ),
        ];
        let short = |chain: &Chain| {
            format!(
                "the limb from {:?} has fewer than two bones",
                self.name(chain[0])
            )
        };
        for (chain, names) in legs {
            let start = self.limb_start(&chain).ok_or_else(|| short(&chain))?;
            self.assign(&chain, start, &names, &mut rig);
        }
        for (chain, names) in arms {
            let start = self.upper_arm(&chain).ok_or_else(|| short(&chain))?;
            self.assign(&chain, start, &names, &mut rig);
        }
        let neck = self.chain(neck);
        let head = neck
            .iter()
            .position(|&j| names_word(self.name(j), "head"))
            .or((neck.len() >= 2).then_some(neck.len() - 1));
        if let Some(h) = head {
            rig[neck[h]] = Some("Head");
            for (&j, name) in neck[..h].iter().zip(["Neck", "Neck1"]) {
                rig[j] = Some(name);
            }
        } else {
            rig[neck[0]] = Some("Neck");
        }
        Ok(rig)
    }

    /// Give the joints of a limb's `chain` the rig's `names` (the joint before the limb, its
    /// two long bones' joints, the joints after them), the long bones starting at `start`.
    fn assign(
        &self,
        chain: &[usize],
        start: usize,
        names: &[&'static str],
        rig: &mut [Option<&'static str>],
    ) {
        if start > 0 {
            rig[chain[start - 1]] = Some(names[0]);
        }
        for (&j, &name) in chain[start..].iter().zip(&names[1..]) {
            rig[j] = Some(name);
        }
    }

    /// Where along an arm's `chain` the upper arm starts: two joints before the hand, the first
    /// joint from the third on with two or more children, all short of [`LONG_SHARE`] of the
    /// chain's longest bone (the fingers, not a twist bone halfway along the forearm, as Unreal's
    /// skeletons have); without one, the joint
    /// before the forearm, the start of the chain's last bone at least [`LONG_SHARE`] of its
    /// longest (the hand's and fingers' bones, and an end site beyond the wrist, are shorter).
    fn upper_arm(&self, chain: &[usize]) -> Option<usize> {
        let bones: Vec<f64> = (0..chain.len()).map(|i| self.bone(chain, i)).collect();
        let longest = bones.iter().copied().fold(0.0, f64::max);
        // Fingers start near the hand; a twist bone halfway along the forearm is no finger.
        let fingers = |j: usize| {
            self.children[j].len() >= 2
                && self.children[j]
                    .iter()
                    .all(|&c| self.bvh.joints()[c].offset.norm() < LONG_SHARE * longest)
        };
        if let Some(hand) = (2..chain.len()).find(|&k| fingers(chain[k])) {
            return Some(hand - 2);
        }
        let forearm = bones.iter().rposition(|&b| b >= LONG_SHARE * longest)?;
        forearm.checked_sub(1)
    }

    /// The body's left from the rest pose: `up × forward`, forward from each leg's ankle to its
    /// toe (the last two joints of the longest bones' chain), `None` where the feet say nothing.
    fn lateral_from_feet(&self, legs: &[Chain; 2], up: &Vector3<f64>) -> Option<Vector3<f64>> {
        let mut forward = Vector3::zeros();
        for chain in legs {
            let start = self.limb_start(chain)?;
            let (&ankle, &toe) = (chain.get(start + 2)?, chain.get(start + 3)?);
            forward += self.rest[toe] - self.rest[ankle];
        }
        let lateral = up.cross(&forward);
        (lateral.norm() > 0.0).then_some(lateral)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_split_into_words_the_way_each_tool_writes_them() {
        let cases = [
            (
                "mixamorig:LeftForeArm",
                vec!["mixamorig", "left", "fore", "arm"],
            ),
            ("LHipJoint", vec!["l", "hip", "joint"]),
            ("upper_arm.L", vec!["upper", "arm", "l"]),
            ("Bip01 R Thigh", vec!["bip", "01", "r", "thigh"]),
            ("lShldr", vec!["l", "shldr"]),
            ("Shoulder_R", vec!["shoulder", "r"]),
            ("spine.001", vec!["spine", "001"]),
        ];
        for (name, want) in cases {
            assert_eq!(words(name), want, "{name}");
        }
        assert_eq!(side_of("mixamorig:LeftArm"), Some(Side::Left));
        assert_eq!(side_of("thigh.R"), Some(Side::Right));
        assert_eq!(side_of("Bip01 L Clavicle"), Some(Side::Left));
        assert_eq!(side_of("rCollar"), Some(Side::Right));
        assert_eq!(side_of("Spine"), None);
        assert_eq!(side_of("LeftRightThing"), None);
    }
}
