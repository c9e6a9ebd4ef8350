//! Indexed triangle meshes as the generator builds them: flat quads and boxes (no normals,
//! so the loader computes flat normals from the winding), UV spheres with smooth normals.
//! Front faces wind counter-clockwise, as glTF defines.

use glam::{Affine3A, Vec2, Vec3};

#[derive(Clone, Debug, Default)]
pub struct Mesh {
    pub positions: Vec<Vec3>,
    /// Smooth shading normals, one per vertex; `None` for flat-shaded meshes.
    pub normals: Option<Vec<Vec3>>,
    pub uvs: Option<Vec<Vec2>>,
    pub indices: Vec<u32>,
}

impl Mesh {
    /// A quadrilateral `a b c d` (in order around its boundary), split along `a c`.
    /// The front face is the one from which `a b c d` runs counter-clockwise.
    pub fn quad(a: Vec3, b: Vec3, c: Vec3, d: Vec3) -> Self {
        Self {
            positions: vec![a, b, c, d],
            normals: None,
            uvs: None,
            indices: vec![0, 1, 2, 0, 2, 3],
        }
    }

    /// A textured quad given by its corners as seen from the front: the texture's first row
    /// (glTF v = 0) runs along the top edge, u grows to the right. The order
    /// top-left, bottom-left, bottom-right, top-right is counter-clockwise from the front.
    pub fn textured_quad(
        top_left: Vec3,
        bottom_left: Vec3,
        bottom_right: Vec3,
        top_right: Vec3,
    ) -> Self {
        let mut q = Self::quad(top_left, bottom_left, bottom_right, top_right);
        q.uvs = Some(vec![
            Vec2::new(0.0, 0.0),
            Vec2::new(0.0, 1.0),
            Vec2::new(1.0, 1.0),
            Vec2::new(1.0, 0.0),
        ]);
        q
    }

    /// A quad whose front face looks towards `toward` (a point on the front side): the
    /// winding is flipped when needed. Measured data (the Cornell box) lists corners in
    /// either order; this keeps every normal pointing where it must.
    pub fn quad_facing(corners: [Vec3; 4], toward: Vec3) -> Self {
        let [a, b, c, d] = corners;
        let mut q = Self::quad(a, b, c, d);
        let normal = (b - a).cross(c - a) + (c - a).cross(d - a);
        let centre = (a + b + c + d) / 4.0;
        if normal.dot(toward - centre) < 0.0 {
            q.flip();
        }
        q
    }

    /// The closed axis-aligned box `[min, max]`, faces pointing out, 12 triangles.
    pub fn cuboid(min: Vec3, max: Vec3) -> Self {
        let centre = (min + max) / 2.0;
        let p = |x: bool, y: bool, z: bool| {
            Vec3::new(
                if x { max.x } else { min.x },
                if y { max.y } else { min.y },
                if z { max.z } else { min.z },
            )
        };
        let faces = [
            [
                p(false, false, false),
                p(false, true, false),
                p(false, true, true),
                p(false, false, true),
            ],
            [
                p(true, false, false),
                p(true, true, false),
                p(true, true, true),
                p(true, false, true),
            ],
            [
                p(false, false, false),
                p(true, false, false),
                p(true, false, true),
                p(false, false, true),
            ],
            [
                p(false, true, false),
                p(true, true, false),
                p(true, true, true),
                p(false, true, true),
            ],
            [
                p(false, false, false),
                p(true, false, false),
                p(true, true, false),
                p(false, true, false),
            ],
            [
                p(false, false, true),
                p(true, false, true),
                p(true, true, true),
                p(false, true, true),
            ],
        ];
        let mut mesh = Self::default();
        for face in faces {
            let centre_of_face = face.iter().copied().sum::<Vec3>() / 4.0;
            // Looking towards a point beyond the face, away from the box centre.
            mesh.append(&Self::quad_facing(face, 2.0 * centre_of_face - centre));
        }
        mesh
    }

    /// A UV sphere of `radius` about the origin: `segments` around the axis (+y is up),
    /// `rings` from pole to pole, smooth normals, u running once around and v from the
    /// north pole (0) to the south pole (1). Pole rows get one triangle per segment, so no
    /// triangle is degenerate. The seam duplicates vertices so that u reaches 1.
    pub fn uv_sphere(radius: f32, segments: u32, rings: u32) -> Self {
        assert!(segments >= 3 && rings >= 2);
        let mut positions = Vec::new();
        let mut normals = Vec::new();
        let mut uvs = Vec::new();
        for ring in 0..=rings {
            let v = ring as f32 / rings as f32;
            let theta = v * std::f32::consts::PI;
            for seg in 0..=segments {
                let u = seg as f32 / segments as f32;
                let phi = u * std::f32::consts::TAU;
                // Exact poles and an exact seam so that shared positions coincide bit for bit.
                let (sin_t, cos_t) = match ring {
                    0 => (0.0, 1.0),
                    r if r == rings => (0.0, -1.0),
                    _ => theta.sin_cos(),
                };
                let (sin_p, cos_p) = if seg == segments {
                    (0.0, 1.0)
                } else {
                    phi.sin_cos()
                };
                let n = Vec3::new(sin_t * cos_p, cos_t, -sin_t * sin_p);
                positions.push(n * radius);
                normals.push(n);
                uvs.push(Vec2::new(u, v));
            }
        }
        let row = segments + 1;
        let mut indices = Vec::new();
        for ring in 0..rings {
            for seg in 0..segments {
                let a = ring * row + seg;
                let b = a + row;
                // Counter-clockwise seen from outside: u grows towards -z at +x (phi turns
                // from +x towards -z), so (a, b, b+1) and (a, b+1, a+1) face outward.
                if ring != 0 {
                    indices.extend([a, b, a + 1]);
                }
                if ring != rings - 1 {
                    indices.extend([a + 1, b, b + 1]);
                }
            }
        }
        Self {
            positions,
            normals: Some(normals),
            uvs: Some(uvs),
            indices,
        }
    }

    /// Reverses every triangle's winding (and the normals with it).
    pub fn flip(&mut self) {
        for tri in self.indices.chunks_exact_mut(3) {
            tri.swap(1, 2);
        }
        if let Some(normals) = &mut self.normals {
            normals.iter_mut().for_each(|n| *n = -*n);
        }
    }

    /// Appends `other`; both must agree on which attributes they carry.
    pub fn append(&mut self, other: &Self) {
        if self.positions.is_empty() {
            *self = other.clone();
            return;
        }
        assert_eq!(
            self.normals.is_some(),
            other.normals.is_some(),
            "mixing smooth and flat meshes"
        );
        assert_eq!(
            self.uvs.is_some(),
            other.uvs.is_some(),
            "mixing textured and untextured meshes"
        );
        let base = self.positions.len() as u32;
        self.positions.extend_from_slice(&other.positions);
        if let (Some(n), Some(m)) = (&mut self.normals, &other.normals) {
            n.extend_from_slice(m);
        }
        if let (Some(u), Some(w)) = (&mut self.uvs, &other.uvs) {
            u.extend_from_slice(w);
        }
        self.indices.extend(other.indices.iter().map(|i| i + base));
    }

    pub fn triangle_count(&self) -> usize {
        self.indices.len() / 3
    }

    /// Sum of the triangle areas, under `transform`.
    pub fn area(&self, transform: Affine3A) -> f32 {
        self.indices
            .chunks_exact(3)
            .map(|t| {
                let [a, b, c] = [t[0], t[1], t[2]]
                    .map(|i| transform.transform_point3(self.positions[i as usize]));
                0.5 * (b - a).cross(c - a).length()
            })
            .sum()
    }
}
