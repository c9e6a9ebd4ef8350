//! glTF node animation (glTF 2.0 §3.11 "Animations"): channels that drive a node's
//! translation, rotation or scale by keyframes with STEP, LINEAR (spherical for rotations) or
//! CUBICSPLINE (Hermite, with in- and out-tangents per key) interpolation, sampled at a time
//! in seconds, and the scene posed at that time: every mesh and punctual light under an
//! animated node moved with it, the camera too when its node moves.
//!
//! Times before the first key take the first value, after the last the last (the
//! specification leaves looping to the application; a sequence that wants a loop passes
//! `t mod duration`). Morph-target weights are not read (a warning says so).
//!
//! The scene is posed from its rest description: each bound vertex range (the triangles of a
//! mesh under node `n`) is mapped by `W_n(t) · W_n(rest)⁻¹`, normals by that map's inverse
//! transpose, tangents as directions, and [`AnimatedScene::at`] builds a [`Scene`] from it
//! (acceleration structure and light sampler built afresh: see `BENCHMARKS.md` for what a
//! frame's rebuild costs).

use glam::{Mat3, Mat4, Quat, Vec3, Vec4};

use crate::camera::Camera;
use crate::scene::{Scene, SceneDescription};

/// How a channel interpolates between keys.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interpolation {
    /// The value of the last key at or before the time.
    Step,
    /// Linear (spherical linear for rotations, shortest arc).
    Linear,
    /// Cubic Hermite spline through the keys with the stored in- and out-tangents.
    CubicSpline,
}

/// What a channel drives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Property {
    Translation,
    /// A unit quaternion (x, y, z, w).
    Rotation,
    Scale,
}

/// One animation channel: a node's property over time.
#[derive(Clone, Debug)]
pub struct Channel {
    pub node: usize,
    pub property: Property,
    pub interpolation: Interpolation,
    /// Key times in seconds, strictly increasing.
    pub times: Vec<f32>,
    /// Values per key (xyz in the first three components for translation and scale, xyzw for
    /// rotation); for CUBICSPLINE three per key: in-tangent, value, out-tangent.
    pub values: Vec<Vec4>,
}

impl Channel {
    /// A channel, checked: keys finite and strictly increasing, as many values as the
    /// interpolation needs, rotations non-zero.
    pub fn new(
        node: usize,
        property: Property,
        interpolation: Interpolation,
        times: Vec<f32>,
        values: Vec<Vec4>,
    ) -> Result<Self, String> {
        if times.is_empty() {
            return Err("an animation sampler has no keys".into());
        }
        if times.iter().any(|t| !t.is_finite()) || times.windows(2).any(|w| w[1] <= w[0]) {
            return Err("an animation sampler's key times must be finite and increasing".into());
        }
        let per_key = if interpolation == Interpolation::CubicSpline {
            3
        } else {
            1
        };
        if values.len() != per_key * times.len() {
            return Err(format!(
                "an animation sampler has {} keys but {} output values (expected {})",
                times.len(),
                values.len(),
                per_key * times.len()
            ));
        }
        if values.iter().any(|v| !v.is_finite()) {
            return Err("an animation sampler has a non-finite output value".into());
        }
        if property == Property::Rotation
            && values
                .iter()
                .skip(usize::from(per_key == 3))
                .step_by(per_key)
                .any(|q| q.length_squared() < 1e-12)
        {
            return Err("an animation sampler has a zero rotation quaternion".into());
        }
        Ok(Self {
            node,
            property,
            interpolation,
            times,
            values,
        })
    }

    /// The key value `k` (the middle of the three for CUBICSPLINE).
    fn value(&self, k: usize) -> Vec4 {
        match self.interpolation {
            Interpolation::CubicSpline => self.values[3 * k + 1],
            _ => self.values[k],
        }
    }

    /// The value at time `t` (for rotations a unit quaternion).
    pub fn sample(&self, t: f32) -> Vec4 {
        let n = self.times.len();
        let v = if t <= self.times[0] || n == 1 {
            self.value(0)
        } else if t >= self.times[n - 1] {
            self.value(n - 1)
        } else {
            // The last key at or before t.
            let k = self.times.partition_point(|&x| x <= t) - 1;
            let (t0, t1) = (self.times[k], self.times[k + 1]);
            let s = (t - t0) / (t1 - t0);
            match self.interpolation {
                Interpolation::Step => self.value(k),
                Interpolation::Linear if self.property == Property::Rotation => {
                    let (a, b) = (
                        Quat::from_vec4(self.value(k)),
                        Quat::from_vec4(self.value(k + 1)),
                    );
                    Vec4::from(a.normalize().slerp(b.normalize(), s))
                }
                Interpolation::Linear => self.value(k).lerp(self.value(k + 1), s),
                Interpolation::CubicSpline => {
                    // glTF 2.0 Appendix C: p(s) = (2s³−3s²+1)v_k + td(s³−2s²+s)b_k
                    //   + (−2s³+3s²)v_{k+1} + td(s³−s²)a_{k+1}, td = t_{k+1} − t_k.
                    let td = t1 - t0;
                    let (s2, s3) = (s * s, s * s * s);
                    let v0 = self.values[3 * k + 1];
                    let b0 = self.values[3 * k + 2];
                    let v1 = self.values[3 * (k + 1) + 1];
                    let a1 = self.values[3 * (k + 1)];
                    v0 * (2.0 * s3 - 3.0 * s2 + 1.0)
                        + b0 * (td * (s3 - 2.0 * s2 + s))
                        + v1 * (-2.0 * s3 + 3.0 * s2)
                        + a1 * (td * (s3 - s2))
                }
            }
        };
        if self.property == Property::Rotation {
            v.normalize_or_zero()
        } else {
            v
        }
    }
}

/// A node's rest transform: translation, rotation, scale, or a matrix (glTF forbids animating
/// a node given by a matrix).
#[derive(Clone, Copy, Debug)]
pub enum Local {
    Trs(Vec3, Quat, Vec3),
    Matrix(Mat4),
}

/// What moves with a node: a range of the description's vertices, a punctual light, the
/// camera.
#[derive(Clone, Debug)]
pub enum Binding {
    Vertices {
        node: usize,
        range: std::ops::Range<usize>,
    },
    Light {
        node: usize,
        light: usize,
    },
    Camera {
        node: usize,
        fov_y: f32,
    },
}

/// A scene's animation: the node hierarchy at rest, its channels and what each node carries.
#[derive(Clone, Debug, Default)]
pub struct Animation {
    /// Each node's rest transform and parent.
    pub nodes: Vec<(Local, Option<usize>)>,
    pub channels: Vec<Channel>,
    pub bindings: Vec<Binding>,
}

impl Animation {
    /// The last key time of any channel (0 without channels).
    pub fn duration(&self) -> f32 {
        self.channels
            .iter()
            .filter_map(|c| c.times.last().copied())
            .fold(0.0, f32::max)
    }

    /// Every node's world transform at time `t` (`None`: at rest).
    pub fn world_transforms(&self, t: Option<f32>) -> Vec<Mat4> {
        let mut local: Vec<Mat4> = self
            .nodes
            .iter()
            .enumerate()
            .map(|(n, (l, _))| match *l {
                Local::Matrix(m) => m,
                Local::Trs(mut tr, mut r, mut s) => {
                    if let Some(t) = t {
                        for c in self.channels.iter().filter(|c| c.node == n) {
                            let v = c.sample(t);
                            match c.property {
                                Property::Translation => tr = v.truncate(),
                                Property::Rotation => r = Quat::from_vec4(v),
                                Property::Scale => s = v.truncate(),
                            }
                        }
                    }
                    Mat4::from_scale_rotation_translation(s, r, tr)
                }
            })
            .collect();
        // Parents before children: resolve by walking up (the hierarchy is acyclic, checked at
        // load).
        let mut world = vec![None; local.len()];
        for n in 0..local.len() {
            let mut chain = vec![n];
            while let Some(p) = self.nodes[*chain.last().unwrap()].1 {
                if world[p].is_some() || chain.len() > self.nodes.len() {
                    break;
                }
                chain.push(p);
            }
            for &m in chain.iter().rev() {
                let parent = self.nodes[m]
                    .1
                    .and_then(|p| world[p])
                    .unwrap_or(Mat4::IDENTITY);
                world[m] = Some(parent * local[m]);
            }
        }
        local.clear();
        world
            .into_iter()
            .map(|w| w.unwrap_or(Mat4::IDENTITY))
            .collect()
    }
}

/// A scene description at rest with its animation.
#[derive(Clone, Debug)]
pub struct AnimatedScene {
    pub rest: SceneDescription,
    pub animation: Animation,
}

impl AnimatedScene {
    /// Whether anything moves.
    pub fn is_animated(&self) -> bool {
        !self.animation.channels.is_empty()
    }

    /// The description posed at time `t` seconds.
    pub fn description_at(&self, t: f32) -> SceneDescription {
        let mut d = self.rest.clone();
        if !self.is_animated() {
            return d;
        }
        let rest = self.animation.world_transforms(None);
        let now = self.animation.world_transforms(Some(t));
        let delta = |n: usize| now[n] * rest[n].inverse();
        for b in &self.animation.bindings {
            match b {
                Binding::Vertices { node, range } => {
                    let m = delta(*node);
                    if m.abs_diff_eq(Mat4::IDENTITY, 0.0) {
                        continue;
                    }
                    let m3 = Mat3::from_mat4(m);
                    let normal = m3.inverse().transpose();
                    for i in range.clone() {
                        d.positions[i] = m.transform_point3(d.positions[i]);
                        if let Some(n) = d.normals.get_mut(i)
                            && *n != Vec3::ZERO
                        {
                            *n = (normal * *n).normalize_or_zero();
                        }
                        if let Some(tg) = d.tangents.get_mut(i)
                            && tg.truncate() != Vec3::ZERO
                        {
                            *tg = (m3 * tg.truncate()).normalize_or_zero().extend(tg.w);
                        }
                    }
                }
                Binding::Light { node, light } => {
                    let m = delta(*node);
                    let l = &mut d.lights[*light];
                    l.position = m.transform_point3(l.position);
                    l.direction = m.transform_vector3(l.direction).normalize_or_zero();
                }
                Binding::Camera { node, fov_y } => {
                    if let Ok(c) = Camera::from_world_matrix(&now[*node], *fov_y) {
                        d.camera = Some(c);
                    }
                }
            }
        }
        d
    }

    /// The scene at time `t` seconds: the posed description with its acceleration structure
    /// and light sampler built.
    pub fn at(&self, t: f32) -> crate::error::Result<Scene> {
        Scene::from_description(self.description_at(t))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: f32) -> Vec4 {
        Vec4::new(x, 0.0, 0.0, 0.0)
    }

    #[test]
    fn step_and_linear_keys_by_hand() {
        let c = Channel::new(
            0,
            Property::Translation,
            Interpolation::Linear,
            vec![1.0, 2.0, 4.0],
            vec![v(0.0), v(10.0), v(20.0)],
        )
        .unwrap();
        assert_eq!(c.sample(0.0).x, 0.0, "before the first key");
        assert_eq!(c.sample(1.5).x, 5.0);
        assert_eq!(c.sample(3.0).x, 15.0);
        assert_eq!(c.sample(9.0).x, 20.0, "after the last key");
        let s = Channel {
            interpolation: Interpolation::Step,
            ..c
        };
        assert_eq!(s.sample(1.99).x, 0.0);
        assert_eq!(s.sample(2.0).x, 10.0);
        assert_eq!(s.sample(3.9).x, 10.0);
    }

    #[test]
    fn rotations_slerp_on_the_shortest_arc() {
        let a = Quat::IDENTITY;
        let b = Quat::from_rotation_y(std::f32::consts::FRAC_PI_2);
        // −b is the same rotation: the shortest arc still passes through 45°.
        let c = Channel::new(
            0,
            Property::Rotation,
            Interpolation::Linear,
            vec![0.0, 1.0],
            vec![Vec4::from(a), -Vec4::from(b)],
        )
        .unwrap();
        let half = Quat::from_vec4(c.sample(0.5));
        let expected = Quat::from_rotation_y(std::f32::consts::FRAC_PI_4);
        assert!(half.angle_between(expected) < 1e-5, "{half:?}");
    }

    #[test]
    fn cubic_spline_keys_by_hand() {
        // Keys (0, v=0, out-tangent 1), (2, in-tangent −3, v=4): at s = 0.5 (t = 1), td = 2,
        // p = 0.5·0 + 2·0.125·1 + 0.5·4 + 2·(−0.125)·(−3) = 0.25 + 2 + 0.75 = 3.
        let c = Channel::new(
            0,
            Property::Scale,
            Interpolation::CubicSpline,
            vec![0.0, 2.0],
            vec![v(9.0), v(0.0), v(1.0), v(-3.0), v(4.0), v(9.0)],
        )
        .unwrap();
        assert!((c.sample(1.0).x - 3.0).abs() < 1e-6, "{}", c.sample(1.0).x);
        assert_eq!(c.sample(0.0).x, 0.0);
        assert_eq!(c.sample(2.0).x, 4.0);
        // Near a key the slope is the key's tangent: out-tangent 1 at t = 0.
        let slope = (c.sample(1e-3).x - c.sample(0.0).x) / 1e-3;
        assert!((slope - 1.0).abs() < 1e-2, "{slope}");
    }

    #[test]
    fn bad_channels_are_refused() {
        let l = Interpolation::Linear;
        let p = Property::Translation;
        assert!(Channel::new(0, p, l, vec![], vec![]).is_err());
        assert!(Channel::new(0, p, l, vec![1.0, 1.0], vec![v(0.0), v(1.0)]).is_err());
        assert!(Channel::new(0, p, l, vec![0.0, f32::NAN], vec![v(0.0), v(1.0)]).is_err());
        assert!(Channel::new(0, p, l, vec![0.0, 1.0], vec![v(0.0)]).is_err());
        assert!(Channel::new(0, p, Interpolation::CubicSpline, vec![0.0], vec![v(0.0)]).is_err());
        assert!(Channel::new(0, p, l, vec![0.0], vec![v(f32::INFINITY)]).is_err());
        assert!(Channel::new(0, Property::Rotation, l, vec![0.0], vec![Vec4::ZERO]).is_err());
    }
}
