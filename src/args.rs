//! Command-line value parsers shared by the subcommands.

use glam::Vec3;

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
