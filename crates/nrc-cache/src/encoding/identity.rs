//! Identity encoding: `x·scale + offset`, unchanged otherwise (reflectances go in as they are).

/// Encodes one scalar.
#[inline(always)]
pub fn forward(x: f32, scale: f32, offset: f32) -> f32 {
    x * scale + offset
}
