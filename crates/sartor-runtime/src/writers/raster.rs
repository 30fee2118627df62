//! A small software rasterizer for previews: triangle meshes with flat Lambert shading, a depth
//! buffer, an orthographic or perspective camera, several panels side by side, 2×2
//! supersampling. Pure Rust; PNG encoding with the `png` feature.
//!
//! Triangles are lit from both sides (garments are open surfaces), by a light at the camera
//! slightly above and to the left: `colour · (0.3 + 0.7 |n · l|)`.

use nalgebra::{Matrix3, Vector3};

use crate::error::{Error, Result};

/// How a [`Camera`] projects.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Projection {
    /// Parallel projection; the panel shows `2 · half_height_m` metres vertically.
    Orthographic {
        /// Half the visible height, metres.
        half_height_m: f32,
    },
    /// Pinhole projection with a vertical field of view.
    Perspective {
        /// Vertical field of view, radians.
        fov_y_rad: f32,
    },
}

/// A camera looking from `eye` at `target`, `up` roughly up.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Camera position, metres.
    pub eye: Vector3<f32>,
    /// The point at the centre of the view.
    pub target: Vector3<f32>,
    /// Up direction (need not be orthogonal to the view direction).
    pub up: Vector3<f32>,
    /// Projection.
    pub projection: Projection,
}

/// The bounding box of every point of `meshes`; the box `[-1, 1]³` when there is none or one
/// is not finite.
fn bounds(meshes: &[RenderMesh<'_>]) -> (Vector3<f32>, Vector3<f32>) {
    let (mut lo, mut hi) = (
        Vector3::repeat(f32::INFINITY),
        Vector3::repeat(f32::NEG_INFINITY),
    );
    for p in meshes.iter().flat_map(|m| m.positions.iter()) {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    if lo.iter().chain(hi.iter()).all(|c| c.is_finite()) {
        (lo, hi)
    } else {
        (Vector3::repeat(-1.0), Vector3::repeat(1.0))
    }
}

impl Camera {
    /// A camera that frames every point of `meshes` (with 5 % of room), looking along
    /// `-direction` (e.g. `+Z` to see the front of a body facing +Z), +Y up.
    pub fn framing(meshes: &[RenderMesh<'_>], direction: Vector3<f32>, perspective: bool) -> Self {
        let (lo, hi) = bounds(meshes);
        let target = (lo + hi) / 2.0;
        let radius = ((hi - lo).norm() / 2.0).max(1e-3) * 1.05;
        let dir = direction.try_normalize(1e-9).unwrap_or_else(Vector3::z);
        let up = if dir.cross(&Vector3::y()).norm() < 1e-3 {
            Vector3::z()
        } else {
            Vector3::y()
        };
        if perspective {
            let fov_y_rad = 30f32.to_radians();
            let distance = radius / (fov_y_rad / 2.0).sin();
            Self {
                eye: target + dir * distance,
                target,
                up,
                projection: Projection::Perspective { fov_y_rad },
            }
        } else {
            Self {
                eye: target + dir * (3.0 * radius),
                target,
                up,
                projection: Projection::Orthographic {
                    half_height_m: radius,
                },
            }
        }
    }

    /// One camera per panel of a strip, each framing its own panel's meshes at one common
    /// scale: every camera has the same projection and distance (the least at which every
    /// panel's box fits its `aspect` = width / height view, with 5 % of room) and looks at the
    /// same height (the middle of the strip's overall vertical extent), centred horizontally
    /// on its own panel's meshes. A body that travels stays in every panel, arms spread wide
    /// stay inside a narrow panel, and heights (a jump, a crouch) read the same in all panels.
    /// Looks along `-direction`, +Y up, as [`Self::framing`].
    pub fn framing_strip(
        panels: &[&[RenderMesh<'_>]],
        direction: Vector3<f32>,
        perspective: bool,
        aspect: f32,
    ) -> Vec<Self> {
        let aspect = if aspect.is_finite() && aspect > 0.0 {
            aspect
        } else {
            1.0
        };
        let bounds: Vec<(Vector3<f32>, Vector3<f32>)> =
            panels.iter().map(|meshes| bounds(meshes)).collect();
        let y_lo = bounds.iter().map(|b| b.0.y).fold(f32::INFINITY, f32::min);
        let y_hi = bounds
            .iter()
            .map(|b| b.1.y)
            .fold(f32::NEG_INFINITY, f32::max);
        let boxes: Vec<(Vector3<f32>, Vector3<f32>)> = bounds
            .iter()
            .map(|(lo, hi)| {
                (
                    Vector3::new(lo.x, y_lo, lo.z),
                    Vector3::new(hi.x, y_hi, hi.z),
                )
            })
            .collect();
        // Camera axes (as `framing` and `view` make them).
        let back = direction.try_normalize(1e-9).unwrap_or_else(Vector3::z);
        let world_up = if back.cross(&Vector3::y()).norm() < 1e-3 {
            Vector3::z()
        } else {
            Vector3::y()
        };
        let right = world_up
            .cross(&back)
            .try_normalize(1e-12)
            .unwrap_or_else(Vector3::x);
        let up = back.cross(&right);
        let fov_y_rad = 30f32.to_radians();
        let tan_y = (fov_y_rad / 2.0).tan();
        let tan_x = tan_y * aspect;
        // Per box corner, offsets from the box centre along right, up and towards the camera,
        // with 5 % of room.
        let corners = |&(lo, hi): &(Vector3<f32>, Vector3<f32>)| {
            let centre = (lo + hi) / 2.0;
            (0..8).map(move |k| {
                let c = Vector3::new(
                    if k & 1 == 0 { lo.x } else { hi.x },
                    if k & 2 == 0 { lo.y } else { hi.y },
                    if k & 4 == 0 { lo.z } else { hi.z },
                ) - centre;
                (
                    1.05 * c.dot(&right).abs(),
                    1.05 * c.dot(&up).abs(),
                    c.dot(&back),
                )
            })
        };
        // Perspective: a corner at (x, y) that is z nearer the camera is seen at x / (d − z):
        // d ≥ x / tan(fov_x / 2) + z and likewise for y. Orthographic: half the view's height
        // covers every corner's height and its width over the aspect.
        let (distance, half_height) =
            boxes
                .iter()
                .flat_map(corners)
                .fold((1e-3f32, 1e-3f32), |(d, h), (x, y, z)| {
                    (
                        d.max(x / tan_x + z).max(y / tan_y + z),
                        h.max(y).max(x / aspect),
                    )
                });
        // Orthographic: far enough back that every box is in front of the camera.
        let depth = boxes
            .iter()
            .flat_map(corners)
            .fold(half_height, |m, (_, _, z)| m.max(z.abs()));
        boxes
            .iter()
            .map(|(lo, hi)| {
                let target = (lo + hi) / 2.0;
                if perspective {
                    Self {
                        eye: target + back * distance,
                        target,
                        up: world_up,
                        projection: Projection::Perspective { fov_y_rad },
                    }
                } else {
                    Self {
                        eye: target + back * (3.0 * depth),
                        target,
                        up: world_up,
                        projection: Projection::Orthographic {
                            half_height_m: half_height,
                        },
                    }
                }
            })
            .collect()
    }

    /// Camera axes as rows: right, up, backward (the camera looks along −z).
    fn view(&self) -> Matrix3<f32> {
        let back = (self.eye - self.target)
            .try_normalize(1e-12)
            .unwrap_or_else(Vector3::z);
        let right = self
            .up
            .cross(&back)
            .try_normalize(1e-12)
            .unwrap_or_else(Vector3::x);
        let up = back.cross(&right);
        Matrix3::from_rows(&[right.transpose(), up.transpose(), back.transpose()])
    }
}

/// One mesh to draw: positions, triangles, linear RGB colour in [0, 1].
#[derive(Clone, Copy, Debug)]
pub struct RenderMesh<'a> {
    /// Vertex positions, metres.
    pub positions: &'a [Vector3<f32>],
    /// Triangles.
    pub faces: &'a [[u32; 3]],
    /// Colour.
    pub color: [f32; 3],
}

/// The colour the writers give a body.
pub const BODY_COLOR: [f32; 3] = [0.80, 0.70, 0.62];
/// The colour the writers give a garment.
pub const GARMENT_COLOR: [f32; 3] = [0.20, 0.42, 0.78];

/// One view: meshes seen by a camera.
#[derive(Clone, Debug)]
pub struct Panel<'a> {
    /// The meshes.
    pub meshes: Vec<RenderMesh<'a>>,
    /// The camera.
    pub camera: Camera,
}

impl<'a> Panel<'a> {
    /// Two perspective views of `meshes`, from the front-right and from the back-left, each
    /// framing `frame_on` (for a body and its garment: the garment to see the cloth, the body to
    /// see where the garment sits on it).
    pub fn front_and_back(meshes: &[RenderMesh<'a>], frame_on: &[RenderMesh<'a>]) -> Vec<Self> {
        [Vector3::new(0.35, 0.1, 1.0), Vector3::new(-0.35, 0.1, -1.0)]
            .into_iter()
            .map(|direction| Panel {
                meshes: meshes.to_vec(),
                camera: Camera::framing(frame_on, direction, true),
            })
            .collect()
    }
}

/// An 8-bit sRGB image, RGBA, row-major from the top.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Image {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// `width · height · 4` bytes.
    pub rgba: Vec<u8>,
}

impl Image {
    /// The RGBA value at `(x, y)`.
    pub fn pixel(&self, x: u32, y: u32) -> [u8; 4] {
        let i = 4 * (y as usize * self.width as usize + x as usize);
        [
            self.rgba[i],
            self.rgba[i + 1],
            self.rgba[i + 2],
            self.rgba[i + 3],
        ]
    }

    /// Encode as PNG (8-bit RGBA).
    #[cfg(feature = "png")]
    pub fn png_bytes(&self) -> Result<Vec<u8>> {
        let mut out = Vec::new();
        let mut encoder = png::Encoder::new(&mut out, self.width, self.height);
        encoder.set_color(png::ColorType::Rgba);
        encoder.set_depth(png::BitDepth::Eight);
        let bad = |e: png::EncodingError| Error::invalid("PNG", e.to_string());
        let mut writer = encoder.write_header().map_err(bad)?;
        writer.write_image_data(&self.rgba).map_err(bad)?;
        writer.finish().map_err(bad)?;
        Ok(out)
    }
}

/// Supersampling factor per axis.
const SS: usize = 2;
/// Pixels between panels.
const GAP: usize = 8;

/// Linear [0, 1] to 8-bit sRGB.
fn srgb(c: f32) -> u8 {
    let c = c.clamp(0.0, 1.0);
    let s = if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0).round() as u8
}

/// Draw one panel into a supersampled colour and depth buffer of `w × h`.
fn draw_panel(
    panel: &Panel<'_>,
    w: usize,
    h: usize,
    color: &mut [Vector3<f32>],
    depth: &mut [f32],
) {
    let view = panel.camera.view();
    let eye = panel.camera.eye;
    let aspect = w as f32 / h as f32;
    // Light from the camera, a little above and to the left, in world space.
    let light = (view.transpose() * Vector3::new(-0.3, 0.5, 1.0)).normalize();
    // Camera-space point → (pixel x, pixel y, depth along the view, larger = farther).
    let project = |p: &Vector3<f32>| -> Option<Vector3<f32>> {
        let c = view * (p - eye);
        let z = -c.z;
        let (sx, sy) = match panel.camera.projection {
            Projection::Orthographic { half_height_m } => {
                (c.x / (half_height_m * aspect), c.y / half_height_m)
            }
            Projection::Perspective { fov_y_rad } => {
                if z <= 1e-4 {
                    return None;
                }
                let f = 1.0 / (fov_y_rad / 2.0).tan();
                (f * c.x / (z * aspect), f * c.y / z)
            }
        };
        Some(Vector3::new(
            (sx + 1.0) * 0.5 * w as f32,
            (1.0 - sy) * 0.5 * h as f32,
            z,
        ))
    };
    for mesh in &panel.meshes {
        let base = Vector3::from(mesh.color);
        for t in mesh.faces {
            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
            let Some(n) = (b - a).cross(&(c - a)).try_normalize(1e-20) else {
                continue;
            };
            let shade = base * (0.3 + 0.7 * n.dot(&light).abs());
            let (Some(pa), Some(pb), Some(pc)) = (project(&a), project(&b), project(&c)) else {
                continue;
            };
            let area = (pb.x - pa.x) * (pc.y - pa.y) - (pb.y - pa.y) * (pc.x - pa.x);
            if area.abs() < 1e-12 {
                continue;
            }
            let x0 = pa.x.min(pb.x).min(pc.x).floor().max(0.0) as usize;
            let x1 = (pa.x.max(pb.x).max(pc.x).ceil() as isize).clamp(0, w as isize) as usize;
            let y0 = pa.y.min(pb.y).min(pc.y).floor().max(0.0) as usize;
            let y1 = (pa.y.max(pb.y).max(pc.y).ceil() as isize).clamp(0, h as isize) as usize;
            for y in y0..y1 {
                for x in x0..x1 {
                    let (px, py) = (x as f32 + 0.5, y as f32 + 0.5);
                    let w0 = ((pb.x - px) * (pc.y - py) - (pb.y - py) * (pc.x - px)) / area;
                    let w1 = ((pc.x - px) * (pa.y - py) - (pc.y - py) * (pa.x - px)) / area;
                    let w2 = 1.0 - w0 - w1;
                    if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                        continue;
                    }
                    let z = w0 * pa.z + w1 * pb.z + w2 * pc.z;
                    let i = y * w + x;
                    if z < depth[i] {
                        depth[i] = z;
                        color[i] = shade;
                    }
                }
            }
        }
    }
}

/// Render `panels` side by side, each `panel_width × height` pixels, separated by 8 pixels of
/// `background` (linear RGB). Errors on empty or oversized images and on meshes that index past
/// their positions.
pub fn render(
    panels: &[Panel<'_>],
    panel_width: u32,
    height: u32,
    background: [f32; 3],
) -> Result<Image> {
    let bad = |m: String| Error::invalid("render", m);
    if panels.is_empty() || panel_width == 0 || height == 0 {
        return Err(bad(format!(
            "{} panels of {panel_width} × {height} pixels: all must be positive",
            panels.len()
        )));
    }
    if panel_width > 8192 || height > 8192 || panels.len() > 64 {
        return Err(bad(format!(
            "{} panels of {panel_width} × {height} pixels is too large",
            panels.len()
        )));
    }
    for (k, panel) in panels.iter().enumerate() {
        for mesh in &panel.meshes {
            let n = mesh.positions.len();
            if mesh.faces.iter().flatten().any(|&i| i as usize >= n) {
                return Err(bad(format!("panel {k}: a face indexes past {n} vertices")));
            }
            if !mesh
                .positions
                .iter()
                .all(|p| p.iter().all(|c| c.is_finite()))
            {
                return Err(bad(format!("panel {k}: a vertex is not finite")));
            }
        }
    }
    let (pw, h) = (panel_width as usize, height as usize);
    let width = panels.len() * pw + (panels.len() - 1) * GAP;
    let bg = Vector3::from(background);
    let mut rgba = vec![0u8; width * h * 4];
    for px in rgba.chunks_exact_mut(4) {
        px.copy_from_slice(&[srgb(bg.x), srgb(bg.y), srgb(bg.z), 255]);
    }
    let (sw, sh) = (pw * SS, h * SS);
    let mut color = vec![bg; sw * sh];
    let mut depth = vec![f32::INFINITY; sw * sh];
    for (k, panel) in panels.iter().enumerate() {
        color.fill(bg);
        depth.fill(f32::INFINITY);
        draw_panel(panel, sw, sh, &mut color, &mut depth);
        let x_offset = k * (pw + GAP);
        for y in 0..h {
            for x in 0..pw {
                let mut sum = Vector3::zeros();
                for dy in 0..SS {
                    for dx in 0..SS {
                        sum += color[(y * SS + dy) * sw + x * SS + dx];
                    }
                }
                let c = sum / (SS * SS) as f32;
                let i = 4 * (y * width + x_offset + x);
                rgba[i..i + 4].copy_from_slice(&[srgb(c.x), srgb(c.y), srgb(c.z), 255]);
            }
        }
    }
    Ok(Image {
        width: width as u32,
        height,
        rgba,
    })
}

/// [`render`] and write the PNG to `path` atomically.
#[cfg(feature = "png")]
pub fn render_png(
    path: &std::path::Path,
    panels: &[Panel<'_>],
    panel_width: u32,
    height: u32,
    background: [f32; 3],
) -> Result<()> {
    let image = render(panels, panel_width, height, background)?;
    sartor_core::io::write_atomic(path, &image.png_bytes()?)?;
    Ok(())
}
