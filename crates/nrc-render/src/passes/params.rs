//! Pass parameters declared once. A pass's settings implement [`Params`] by visiting each of
//! their keys with its [`Key`] (name, help, range) and the field it sets; parsing
//! (`restir-di:light=16,k=3`), printing (the keys that differ from the variant's defaults),
//! the `--pass` help text and the error messages are all made from that one visit, so they
//! cannot drift apart. Which keys a value takes may depend on its variant (world-space ReSTIR
//! GI has cells, screen-space neighbours; `nrc-restir` has no probe volume).

use std::fmt::Write as _;

use glam::UVec3;

use crate::error::PassError;

/// One key of a pass's parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Key {
    /// Its name after the pass's colon.
    pub name: &'static str,
    pub help: &'static str,
    /// Bounds of a numeric value: `max` inclusive, `min` too unless `open_min`.
    pub min: f64,
    pub max: f64,
    pub open_min: bool,
}

impl Key {
    /// A key without bounds.
    pub const fn new(name: &'static str, help: &'static str) -> Self {
        Self {
            name,
            help,
            min: f64::NEG_INFINITY,
            max: f64::INFINITY,
            open_min: false,
        }
    }

    /// The key with its value bounded to `[min, max]`.
    pub const fn range(self, min: f64, max: f64) -> Self {
        Self { min, max, ..self }
    }

    /// The key with a positive value (0 excluded), at most `max`.
    pub const fn positive(self, max: f64) -> Self {
        Self {
            min: 0.0,
            max,
            open_min: true,
            ..self
        }
    }

    /// Whether `x` lies within the bounds.
    fn admits(&self, x: f64) -> bool {
        (if self.open_min {
            self.min < x
        } else {
            self.min <= x
        }) && x <= self.max
    }
}

/// A parameter's value as text.
pub trait Value {
    /// Sets the value from `text`; `None` when it does not parse.
    fn read(&mut self, text: &str) -> Option<()>;
    fn write(&self) -> String;
    /// What `read` takes, for help texts (`N`, `X`, `0|1`, `full|indirect|nrc`).
    fn grammar(&self) -> &'static str;
    /// The value as a number, for the range check.
    fn number(&self) -> Option<f64> {
        None
    }
}

impl Value for u32 {
    fn read(&mut self, text: &str) -> Option<()> {
        *self = text.parse().ok()?;
        Some(())
    }
    fn write(&self) -> String {
        self.to_string()
    }
    fn grammar(&self) -> &'static str {
        "N"
    }
    fn number(&self) -> Option<f64> {
        Some(*self as f64)
    }
}

/// A count, or `auto` for one chosen where it is used.
impl Value for Option<u32> {
    fn read(&mut self, text: &str) -> Option<()> {
        *self = if text == "auto" {
            None
        } else {
            Some(text.parse().ok()?)
        };
        Some(())
    }
    fn write(&self) -> String {
        self.map_or("auto".into(), |n| n.to_string())
    }
    fn grammar(&self) -> &'static str {
        "N|auto"
    }
    fn number(&self) -> Option<f64> {
        self.map(f64::from)
    }
}

impl Value for f32 {
    fn read(&mut self, text: &str) -> Option<()> {
        *self = text.parse().ok().filter(|x: &f32| x.is_finite())?;
        Some(())
    }
    fn write(&self) -> String {
        self.to_string()
    }
    fn grammar(&self) -> &'static str {
        "X"
    }
    fn number(&self) -> Option<f64> {
        Some(*self as f64)
    }
}

impl Value for bool {
    fn read(&mut self, text: &str) -> Option<()> {
        *self = match text {
            "0" => false,
            "1" => true,
            _ => return None,
        };
        Some(())
    }
    fn write(&self) -> String {
        (*self as u8).to_string()
    }
    fn grammar(&self) -> &'static str {
        "0|1"
    }
}

/// Counts per axis: `N` (the same along each) or `XxYxZ`; `auto` when chosen elsewhere.
impl Value for Option<UVec3> {
    fn read(&mut self, text: &str) -> Option<()> {
        if text == "auto" {
            *self = None;
            return Some(());
        }
        let n: Vec<u32> = text
            .split('x')
            .map(|p| p.parse().ok())
            .collect::<Option<_>>()?;
        *self = Some(match n[..] {
            [n] => UVec3::splat(n),
            [x, y, z] => UVec3::new(x, y, z),
            _ => return None,
        });
        Some(())
    }
    fn write(&self) -> String {
        match self {
            None => "auto".into(),
            Some(c) if c.x == c.y && c.y == c.z => c.x.to_string(),
            Some(c) => format!("{}x{}x{}", c.x, c.y, c.z),
        }
    }
    fn grammar(&self) -> &'static str {
        "N|XxYxZ|auto"
    }
    fn number(&self) -> Option<f64> {
        // The largest axis, so that no axis exceeds the key's bound.
        self.map(|c| c.max_element() as f64)
    }
}

/// Settings whose parameters are declared once (see the module documentation).
pub trait Params {
    /// Calls `f` with every key these settings take, in their variant, and the field it sets.
    fn visit(&mut self, f: &mut dyn FnMut(&Key, &mut dyn Value));
}

/// One parameter as it stands: its key, what it takes and its value.
#[derive(Clone, Debug, PartialEq)]
pub struct Param {
    pub key: Key,
    pub grammar: &'static str,
    pub value: String,
}

/// The parameters `settings` take, with their values.
pub fn list<S: Params + Clone>(settings: &S) -> Vec<Param> {
    let mut s = settings.clone();
    let mut out = Vec::new();
    s.visit(&mut |key, value| {
        out.push(Param {
            key: *key,
            grammar: value.grammar(),
            value: value.write(),
        })
    });
    out
}

/// Sets the comma-separated `KEY=VALUE` parameters `params` of the pass named `pass`.
pub fn set<S: Params>(pass: &str, settings: &mut S, params: &str) -> Result<(), PassError> {
    for kv in params.split(',').filter(|p| !p.is_empty()) {
        let (name, text) = kv.split_once('=').ok_or_else(|| PassError::NotKeyValue {
            pass: pass.to_string(),
            text: kv.to_string(),
        })?;
        let mut known = Vec::new();
        let mut outcome = None;
        settings.visit(&mut |key, value| {
            known.push(key.name);
            if key.name != name {
                return;
            }
            let in_range = |v: &dyn Value| v.number().is_none_or(|x| key.admits(x));
            outcome = Some(match value.read(text) {
                Some(()) if in_range(value) => Ok(()),
                _ => Err(PassError::BadValue {
                    pass: pass.to_string(),
                    key: name.to_string(),
                    value: text.to_string(),
                    expected: format!("{}{}", value.grammar(), bounds(key, " in ")),
                }),
            });
        });
        match outcome {
            Some(r) => r?,
            None if known.is_empty() => {
                return Err(PassError::NoParameters {
                    pass: pass.to_string(),
                    key: name.to_string(),
                });
            }
            None => {
                return Err(PassError::UnknownParameter {
                    pass: pass.to_string(),
                    key: name.to_string(),
                    known: known.join(", "),
                });
            }
        }
    }
    Ok(())
}

/// The parameters of `settings` that differ from `base`'s, as `KEY=VALUE,...` (empty when
/// none do).
pub fn changed<S: Params + Clone>(settings: &S, base: &S) -> String {
    let base = list(base);
    list(settings)
        .into_iter()
        .filter(|p| {
            base.iter()
                .find(|b| b.key.name == p.key.name)
                .is_none_or(|b| b.value != p.value)
        })
        .map(|p| format!("{}={}", p.key.name, p.value))
        .collect::<Vec<_>>()
        .join(",")
}

/// `base` followed by `:` and the parameters that differ from the defaults, where any do.
pub fn name<S: Params + Clone>(base_name: &str, settings: &S, defaults: &S) -> String {
    match changed(settings, defaults) {
        p if p.is_empty() => base_name.to_string(),
        p => format!("{base_name}:{p}"),
    }
}

/// `key`'s bounds after `sep`, where it has any.
fn bounds(key: &Key, sep: &str) -> String {
    let open = if key.open_min { "(" } else { "[" };
    let above = if key.open_min { ">" } else { "≥" };
    match (key.min.is_finite(), key.max.is_finite()) {
        (true, true) => format!("{sep}{open}{}, {}]", key.min, key.max),
        (true, false) => format!("{sep}{above} {}", key.min),
        (false, true) => format!("{sep}≤ {}", key.max),
        (false, false) => String::new(),
    }
}

/// One line per parameter: `KEY=GRAMMAR  help (default D, in [a, b])`.
pub fn help(params: &[Param]) -> String {
    let mut out = String::new();
    for p in params {
        let _ = writeln!(
            out,
            "    {}={}  {} (default {}{})",
            p.key.name,
            p.grammar,
            p.key.help,
            p.value,
            bounds(&p.key, ", ")
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Clone, Debug, Default, PartialEq)]
    struct Demo {
        count: u32,
        scale: f32,
        on: bool,
        wide: bool,
        extra: u32,
    }

    impl Params for Demo {
        fn visit(&mut self, f: &mut dyn FnMut(&Key, &mut dyn Value)) {
            f(
                &Key::new("count", "a count").range(0.0, 8.0),
                &mut self.count,
            );
            f(
                &Key::new("scale", "a scale").range(0.0, 1.0),
                &mut self.scale,
            );
            f(&Key::new("on", "a switch"), &mut self.on);
            if self.wide {
                f(&Key::new("extra", "only when wide"), &mut self.extra);
            }
        }
    }

    #[test]
    fn parse_print_range_and_variant_keys() {
        let mut d = Demo::default();
        set("demo", &mut d, "count=3,on=1,scale=0.5").unwrap();
        assert_eq!((d.count, d.on, d.scale), (3, true, 0.5));
        assert_eq!(
            name("demo", &d, &Demo::default()),
            "demo:count=3,scale=0.5,on=1"
        );
        assert_eq!(name("demo", &Demo::default(), &Demo::default()), "demo");
        for bad in [
            "count=9",
            "count=-1",
            "scale=nan",
            "scale=2",
            "on=2",
            "extra=1",
            "count",
        ] {
            let e = set("demo", &mut Demo::default(), bad)
                .unwrap_err()
                .to_string();
            assert!(e.starts_with("pass `demo`: "), "{bad}: {e}");
        }
        let e = set("demo", &mut Demo::default(), "extra=1")
            .unwrap_err()
            .to_string();
        assert!(e.contains("known: count, scale, on)"), "{e}");
        let mut wide = Demo {
            wide: true,
            ..Default::default()
        };
        set("demo", &mut wide, "extra=7").unwrap();
        assert_eq!(wide.extra, 7);
        let h = help(&list(&wide));
        assert!(h.contains("count=N  a count (default 0, [0, 8])"), "{h}");
        assert!(h.contains("extra=N  only when wide (default 7)"), "{h}");
    }

    #[test]
    fn counts_per_axis() {
        let mut c: Option<UVec3> = None;
        assert_eq!(c.write(), "auto");
        c.read("4").unwrap();
        assert_eq!(c, Some(UVec3::splat(4)));
        assert_eq!(c.write(), "4");
        c.read("2x3x4").unwrap();
        assert_eq!(c.write(), "2x3x4");
        assert!(c.read("2x3").is_none() && c.read("x").is_none());
        c.read("auto").unwrap();
        assert_eq!(c, None);
        // The bound applies to every axis.
        let key = Key::new("probes", "").range(1.0, 64.0);
        c.read("1x1x500").unwrap();
        assert!(!key.admits(c.number().unwrap()));
    }
}
