//! Where the cache runs: burn's Flex CPU backend or wgpu, and how training is computed there.

use std::fmt;
use std::str::FromStr;

use burn::tensor::Device;

use crate::error::CacheError;

/// The compute device of a cache.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CacheDevice {
    /// burn's Flex CPU backend.
    Cpu,
    /// burn's wgpu backend (any adapter wgpu offers, including software Vulkan).
    Wgpu,
}

impl fmt::Display for CacheDevice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Cpu => "cpu",
            Self::Wgpu => "wgpu",
        })
    }
}

impl FromStr for CacheDevice {
    type Err = CacheError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "cpu" | "flex" => Ok(Self::Cpu),
            "wgpu" | "gpu" => Ok(Self::Wgpu),
            other => Err(CacheError::Device(format!(
                "unknown device {other:?} (expected cpu or wgpu)"
            ))),
        }
    }
}

impl CacheDevice {
    /// The default device: wgpu when a hardware GPU adapter exists, the CPU otherwise (a
    /// software rasteriser such as lavapipe is slower than Flex). Returns the reason too.
    pub fn auto() -> (Self, String) {
        let adapters = crate::gpu::adapters();
        match adapters
            .iter()
            .find(|a| a.device_type != burn::backend::wgpu::wgpu::DeviceType::Cpu)
        {
            Some(a) => (
                Self::Wgpu,
                format!("hardware GPU adapter {} ({:?})", a.name, a.backend),
            ),
            None if adapters.is_empty() => (Self::Cpu, "no wgpu adapter".into()),
            None => (
                Self::Cpu,
                format!(
                    "only software wgpu adapters ({})",
                    adapters
                        .iter()
                        .map(|a| a.name.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            ),
        }
    }

    /// The burn device (not autodiff).
    pub fn burn_device(self) -> Result<Device, CacheError> {
        match self {
            Self::Cpu => Ok(Device::flex()),
            Self::Wgpu => crate::gpu::wgpu_device().map_err(CacheError::Device),
        }
    }

    /// The default computation on this device: the fused step (rayon kernels on Flex, CubeCL
    /// kernels on wgpu).
    pub fn default_path(self) -> ComputePath {
        ComputePath::Fused
    }
}

/// How a training step and inference are computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ComputePath {
    /// The fused step: tile-fused encode + MLP + loss + backward, sparse Adam and lazy EMA for
    /// the hash table (rayon kernels on Flex; on wgpu four CubeCL dispatches a step, the
    /// `nrc-gpu` crate).
    Fused,
    /// burn autodiff over custom ops: the hash-grid op (WGSL on wgpu, rayon on Flex) and the
    /// fused MLP op where the backend has one (Flex), otherwise matmuls; tensor-op Adam/EMA.
    CustomOps,
    /// burn autodiff over generic tensor ops only (gather-based hash grid, matmul MLP): the
    /// reference the custom ops are measured against.
    Unfused,
}

impl fmt::Display for ComputePath {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Fused => "fused",
            Self::CustomOps => "custom-ops",
            Self::Unfused => "unfused",
        })
    }
}
