//! The registry's tests: every pass name parses, prints and round-trips; every key the help
//! lists parses, prints and round-trips; no other key parses.

use crate::error::PassError;
use std::collections::BTreeSet;

use super::*;
use crate::passes::params::Param;

#[test]
fn names_parse_print_and_round_trip_through_json() {
    for name in [
        "pt",
        "pt-nonee",
        "pt-light",
        "cache",
        "cache-first",
        "cache-diffuse:0.5",
        "cache-bth:8",
        "cache-nonee",
        "cache-first-nonee",
        "ir",
        "smc-ir",
        "smc-ir-nrc:vpls=256,mmax=8,residual=1",
        "ir:per_pixel=0,clamp=0.05,indirect=1",
        "restir-di",
        "restir-di-biased",
        "restir-di:light=16,k=3",
        "restir-di-biased:bsdf=0,radius=10,mcap=4,temporal=0,jitter=0",
        "restir-gi",
        "restir-gi-biased",
        "restir-gi-nrc",
        "restir-gi-biased-nrc:k=5,radius=12",
        "wsrestir-gi",
        "wsrestir-gi-nrc",
        "wsrestir-gi-biased:samples=5,cell=0.05,dmin=0.02,mcap=10,temporal=0,jacobian=0,jitter=0",
        "cache-secondary",
        "ddgi-secondary",
        "ddgi-first:probes=4,rays=64,hysteresis=0.9,radiance=indirect",
        "ddgi-secondary:radiance=nrc",
        "ddgi-secondary:relocate=1,classify=1",
        "ddgi-restir",
        "nrc-restir",
        "ddgi-nrc-restir",
        "ddgi-restir:light=4,bsdf=2,k=0,radius=10,mcap=6,temporal=1,clamp=0,residual=0,requery=1,jitter=0,smooth=0.5,footprint=0.2,direct=0,probes=4,rays=64,hysteresis=0.9,relocate=1,classify=1,attenuation=0.5",
        "nrc-restir:clamp=0.05",
    ] {
        let spec: PassSpec = name.parse().unwrap();
        assert_eq!(spec.to_string(), name);
        let json = serde_json::to_string(&spec).unwrap();
        assert_eq!(serde_json::from_str::<PassSpec>(&json).unwrap(), spec);
    }
    assert_eq!(
        "cache-spread".parse::<PassSpec>().unwrap().to_string(),
        "cache"
    );
    for bad in [
        "",
        "ptx",
        "cache-",
        "cache--nonee",
        "cache-first--nonee",
        "cache-last",
        "cachefirst",
        "cache-spread:0",
        "pt-first",
        "restir-di-",
        "restir-di:light",
        "restir-di:light=x",
        "restir-di:nope=1",
        "restir-di:light=0,bsdf=0",
        "restir-di:mcap=-1",
        "restir-di:light=4294967295,bsdf=1",
        "restir-di:k=100000",
        "restir-gi:k=4000000000",
        "wsrestir-gi:samples=100000",
        "ddgi-secondary:probes=100",
        "ddgi-secondary:rays=1000000000",
        "restir-di:radius=nan",
        "restir-gi-nrc-biased",
        "restir-gi:samples=3",
        "wsrestir-gi:k=3",
        "wsrestir-gi:cell=0",
        "ddgi-",
        "ddgi-secondary:probes=0",
        "ddgi-secondary:hysteresis=1",
        "ddgi-secondary:radiance=x",
        "ddgi-restirx",
        "nrc-restir:probes=4",
        "nrc-restir:requery=1",
        "ddgi-restir:bsdf=0",
        "nrc-restir:classify=1",
        "ddgi-restir:clamp=-1",
        "ddgi-restir:clamp=nan",
        "ddgi-nrc-restir:probes=0",
    ] {
        let e = bad.parse::<PassSpec>().unwrap_err().to_string();
        assert!(e.contains("pass"), "{bad}: {e}");
    }
    assert!(serde_json::from_str::<PassSpec>("\"cache-nope\"").is_err());
}

/// A valid value of `p` other than its current one.
fn another(p: &Param) -> String {
    let v = &p.value;
    match p.grammar {
        "0|1" => if v == "0" { "1" } else { "0" }.into(),
        "N" => {
            let n: f64 = v.parse().unwrap();
            if n + 1.0 <= p.key.max {
                n + 1.0
            } else {
                n - 1.0
            }
            .to_string()
        }
        "X" => {
            let x: f32 = v.parse().unwrap();
            if x > 0.0 { x * 0.5 } else { 0.5 }.to_string()
        }
        "N|XxYxZ|auto" => "4".into(),
        "N|auto" => if v == "auto" { "64" } else { "auto" }.into(),
        "full|indirect|nrc" => "indirect".into(),
        g => panic!("no alternative for grammar {g}"),
    }
}

#[test]
fn every_key_the_help_lists_parses_prints_and_round_trips() {
    let help = help();
    let variants: Vec<(&PassKind, PassSpec)> = REGISTRY
        .iter()
        .flat_map(|k| (k.variants)().into_iter().map(move |v| (*k, v)))
        .collect();
    assert!(variants.len() >= REGISTRY.len());
    let mut every_key: BTreeSet<&str> = ["nope", "light_candidates", "seed"].into();
    for (kind, v) in &variants {
        let name = v.to_string();
        assert!(!name.contains(':'), "{name}: a variant has no parameters");
        let (found, again) = find(&name).unwrap();
        assert!(
            std::ptr::eq(found, *kind),
            "{name} is claimed by its own kind"
        );
        assert_eq!(&again.unwrap(), v);
        assert!(help.contains(kind.grammar) && help.contains(kind.about));
        for p in v.params() {
            every_key.insert(p.key.name);
            let line = format!(
                "{}={}  {} (default {}",
                p.key.name, p.grammar, p.key.help, p.value
            );
            assert!(help.contains(&line), "the help lacks {line}");
            let value = another(&p);
            let with = format!("{name}:{}={value}", p.key.name);
            let spec: PassSpec = with.parse().unwrap_or_else(|e| panic!("{with}: {e}"));
            assert_ne!(&spec, v, "{with}");
            let printed = spec.to_string();
            assert!(
                printed.contains(&format!("{}=", p.key.name)),
                "{with} printed {printed}"
            );
            assert_eq!(printed.parse::<PassSpec>().unwrap(), spec, "{printed}");
            let json = serde_json::to_string(&spec).unwrap();
            assert_eq!(serde_json::from_str::<PassSpec>(&json).unwrap(), spec);
            let changed = spec.params().into_iter().find(|q| q.key.name == p.key.name);
            assert_ne!(changed.unwrap().value, p.value, "{with}");
        }
    }
    // No key is parsed that the variant's help does not list.
    for (_, v) in &variants {
        let listed: Vec<&str> = v.params().iter().map(|p| p.key.name).collect();
        for key in &every_key {
            if listed.contains(key) {
                continue;
            }
            let with = format!("{v}:{key}=1");
            let e = with.parse::<PassSpec>().unwrap_err();
            assert!(
                matches!(
                    e,
                    PassError::UnknownParameter { .. }
                        | PassError::NoParameters { .. }
                        | PassError::TerminationParameters { .. }
                ),
                "{with}: {e}"
            );
        }
    }
}
