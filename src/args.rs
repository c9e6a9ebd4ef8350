//! Command-line value parsers shared by the subcommands.

use glam::Vec3;
use nrc_render::{LightStrategy, PathTracer};

/// Path depth options: every command that traces paths, so that methods and their reference
/// estimate the same image.
#[derive(clap::Args, Debug, Clone)]
pub struct DepthArgs {
    /// Maximum number of path segments, as Mitsuba counts them: 1 shows emitters seen
    /// directly, 2 adds direct illumination, 3 one indirect bounce, ...; 0 or -1: unlimited
    /// (Russian roulette ends paths).
    #[arg(long, default_value_t = -1, allow_negative_numbers = true)]
    pub max_depth: i32,

    /// Number of scattering events after which Russian roulette may end a path
    /// (Mitsuba's rr_depth), at most 1000.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u32).range(0..=1000))]
    pub rr_depth: u32,
}

impl DepthArgs {
    /// The reference path tracer (NEE and BSDF sampling by MIS) at these depths.
    pub fn tracer(&self) -> PathTracer {
        PathTracer {
            max_depth: self.max_depth,
            rr_depth: self.rr_depth,
            ..PathTracer::default()
        }
    }
}

/// Direct-illumination estimators, as named on the command line.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Strategy {
    /// Next-event estimation and BSDF sampling combined by MIS (power heuristic).
    Mis,
    /// BSDF sampling only (next-event estimation off).
    Bsdf,
    /// Next-event estimation only.
    Light,
}

/// The path depth and the direct-illumination estimators (`render`, `train`, `bench trace`).
#[derive(clap::Args, Debug, Clone)]
pub struct TracerArgs {
    #[command(flatten)]
    pub depth: DepthArgs,

    /// Estimators of direct illumination.
    #[arg(long, value_enum, default_value_t = Strategy::Mis)]
    pub strategy: Strategy,
}

impl TracerArgs {
    pub fn tracer(&self) -> PathTracer {
        PathTracer {
            strategy: match self.strategy {
                Strategy::Mis => LightStrategy::Mis,
                Strategy::Bsdf => LightStrategy::BsdfOnly,
                Strategy::Light => LightStrategy::LightOnly,
            },
            ..self.depth.tracer()
        }
    }
}

/// Parses `x,y,z` into a vector of three finite numbers.
pub fn parse_vec3(s: &str) -> Result<Vec3, String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    if parts.len() != 3 {
        return Err(format!(
            "expected three comma-separated numbers x,y,z, got `{s}`"
        ));
    }
    let mut v = [0.0f32; 3];
    for (slot, p) in v.iter_mut().zip(&parts) {
        let x: f32 = p
            .parse()
            .map_err(|_| format!("`{p}` is not a number (in `{s}`)"))?;
        if !x.is_finite() {
            return Err(format!("`{p}` is not a finite number (in `{s}`)"));
        }
        *slot = x;
    }
    Ok(Vec3::from_array(v))
}

/// Parses a non-negative RGB radiance `r,g,b` (or a single number for grey).
pub fn parse_rgb(s: &str) -> Result<Vec3, String> {
    let v = if s.contains(',') {
        parse_vec3(s)?
    } else {
        let x: f32 = s
            .trim()
            .parse()
            .map_err(|_| format!("`{s}` is not a number"))?;
        Vec3::splat(x)
    };
    if !v.is_finite() || v.min_element() < 0.0 {
        return Err(format!(
            "radiance must be finite and non-negative, got `{s}`"
        ));
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vec3_parsing() {
        assert_eq!(parse_vec3("1, -2.5,3").unwrap(), Vec3::new(1.0, -2.5, 3.0));
        assert!(parse_vec3("1,2").is_err());
        assert!(parse_vec3("1,2,x").is_err());
        assert!(parse_vec3("1,2,NaN").is_err());
        assert_eq!(parse_rgb("0.5").unwrap(), Vec3::splat(0.5));
        assert!(parse_rgb("1,-1,0").is_err());
    }
}
