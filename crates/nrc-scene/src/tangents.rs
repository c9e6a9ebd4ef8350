//! Tangent frames for tangent-space normal maps: glTF's `TANGENT` attribute where the file
//! has one, else MikkTSpace tangents (the `mikktspace` crate, the algorithm glTF names for
//! files without tangents), kept per triangle corner as MikkTSpace produces them.

use glam::{Vec2, Vec3, Vec4};

/// Per triangle, the tangents (xyz, w = bitangent sign) of its three corners. `triangles`:
/// vertex indices and geometric normal of each triangle; `tex_coord(t)`: the texture
/// coordinate set triangle `t`'s normal map reads, `None` for triangles without one (their
/// tangents stay zero). File tangents (`tangents`, per vertex, or empty) are used where
/// present and non-zero at all three corners.
pub fn corner_tangents(
    positions: &[Vec3],
    normals: &[Vec3],
    uvs: [&[Vec2]; 2],
    tangents: &[Vec4],
    triangles: &[([u32; 3], Vec3)],
    tex_coord: impl Fn(usize) -> Option<u32>,
) -> Vec<[Vec4; 3]> {
    let mut out = vec![[Vec4::ZERO; 3]; triangles.len()];
    let mut generate: Vec<(usize, u32)> = Vec::new();
    for (t, (v, _)) in triangles.iter().enumerate() {
        let Some(set) = tex_coord(t) else { continue };
        let from_file = (!tangents.is_empty())
            .then(|| v.map(|k| tangents[k as usize]))
            .filter(|c| {
                c.iter()
                    .all(|q| q.truncate() != Vec3::ZERO && q.is_finite())
            });
        match from_file {
            Some(c) => out[t] = c,
            None => generate.push((t, set)),
        }
    }
    if generate.is_empty() {
        return out;
    }
    let mut geometry = Mikk {
        positions,
        normals,
        uvs,
        triangles,
        faces: &generate,
        out: &mut out,
    };
    // `false` only when there is nothing to process; degenerate input gets zero tangents,
    // which shading skips (the interpolated normal is used unmapped).
    mikktspace::generate_tangents(&mut geometry);
    out
}

struct Mikk<'a> {
    positions: &'a [Vec3],
    normals: &'a [Vec3],
    uvs: [&'a [Vec2]; 2],
    triangles: &'a [([u32; 3], Vec3)],
    /// (triangle, texture coordinate set) of the faces to generate.
    faces: &'a [(usize, u32)],
    out: &'a mut [[Vec4; 3]],
}

impl Mikk<'_> {
    fn vertex(&self, face: usize, vert: usize) -> u32 {
        self.triangles[self.faces[face].0].0[vert]
    }
}

impl mikktspace::Geometry for Mikk<'_> {
    fn num_faces(&self) -> usize {
        self.faces.len()
    }

    fn num_vertices_of_face(&self, _face: usize) -> usize {
        3
    }

    fn position(&self, face: usize, vert: usize) -> [f32; 3] {
        self.positions[self.vertex(face, vert) as usize].to_array()
    }

    fn normal(&self, face: usize, vert: usize) -> [f32; 3] {
        let n = self
            .normals
            .get(self.vertex(face, vert) as usize)
            .copied()
            .filter(|n| *n != Vec3::ZERO)
            .unwrap_or(self.triangles[self.faces[face].0].1);
        n.to_array()
    }

    fn tex_coord(&self, face: usize, vert: usize) -> [f32; 2] {
        let set = self.uvs[(self.faces[face].1 as usize).min(1)];
        set.get(self.vertex(face, vert) as usize)
            .copied()
            .unwrap_or(Vec2::ZERO)
            .to_array()
    }

    fn set_tangent_encoded(&mut self, tangent: [f32; 4], face: usize, vert: usize) {
        let t = self.faces[face].0;
        self.out[t][vert] = Vec4::from_array(tangent);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A quad in the xy plane with u along +x and v along +y has tangent +x; mirroring v flips
    /// the bitangent's sign.
    #[test]
    fn tangents_follow_the_texture_axes() {
        let positions = [Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y];
        let tris = [([0, 1, 2], Vec3::Z), ([0, 2, 3], Vec3::Z)];
        for (flip, sign) in [(false, 1.0), (true, -1.0)] {
            let uvs: Vec<Vec2> = positions
                .iter()
                .map(|p| Vec2::new(p.x, if flip { 1.0 - p.y } else { p.y }))
                .collect();
            let t = corner_tangents(&positions, &[], [&uvs, &[]], &[], &tris, |_| Some(0));
            for c in t.iter().flatten() {
                assert!((c.truncate() - Vec3::X).length() < 1e-5, "{c}");
                assert_eq!(c.w, sign, "flip {flip}");
            }
        }
    }
}
