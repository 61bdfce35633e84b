//! Run-time choice of the Burn device from a name (`--device`, the experiment TOML).
//!
//! Which backends exist is decided at build time by cargo features; asking for one that is not
//! compiled in is an error that names the feature to enable.

use burn::module::Module;
use burn::prelude::Device;

/// Why a device name could not be turned into a device.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum DeviceError {
    /// The name is not one this program knows.
    #[error("unknown device `{name}`: expected one of cpu, flex, ndarray, wgpu, cuda or cuda:N")]
    Unknown {
        /// The name that was asked for.
        name: String,
    },
    /// The backend exists but this binary was built without it.
    #[error(
        "device `{name}` needs the `{feature}` backend, which this build does not include: rebuild with `--features {feature}`"
    )]
    NotCompiled {
        /// The name that was asked for.
        name: String,
        /// The cargo feature that compiles the backend in.
        feature: &'static str,
    },
}

/// The backends this binary was compiled with, in the order `cpu` prefers them.
pub fn compiled_backends() -> Vec<&'static str> {
    let mut out = Vec::new();
    if cfg!(feature = "flex") {
        out.push("flex");
    }
    if cfg!(feature = "ndarray") {
        out.push("ndarray");
    }
    if cfg!(feature = "wgpu-base") {
        out.push("wgpu");
    }
    if cfg!(feature = "cuda") {
        out.push("cuda");
    }
    out
}

/// Every CPU device compiled in (flex first), for tests that compare backends.
#[allow(clippy::vec_init_then_push)] // the pushes depend on cfg
pub fn cpu_devices() -> Vec<(&'static str, Device)> {
    let mut out = Vec::new();
    #[cfg(feature = "flex")]
    out.push(("flex", Device::flex()));
    #[cfg(feature = "ndarray")]
    #[allow(deprecated)]
    out.push(("ndarray", Device::ndarray()));
    out
}

/// Whether `device` is one of the CPU backends (flex, ndarray), with or without autodiff: the
/// host's memory, where reading a tensor costs no copy over a bus.
pub fn is_host(device: &Device) -> bool {
    cpu_devices().iter().any(|(_, d)| d == device)
}

/// The most bytes `device` allocates in one buffer, where its backend says (the cubecl
/// backends: wgpu's storage-binding and buffer limits, CUDA's); `None` for the CPU backends.
pub fn max_buffer_bytes(device: &Device) -> Option<u64> {
    #[cfg(feature = "gpu")]
    {
        let cube = crate::cube_tensor::cube_device(device)?;
        Some(cube.client().properties().memory.max_page_size)
    }
    #[cfg(not(feature = "gpu"))]
    {
        let _ = device;
        None
    }
}

/// The default CPU device: flex when compiled in, else ndarray.
///
/// # Panics
/// When the binary was built without any CPU backend (a build configuration error, not user input).
pub fn cpu() -> Device {
    cpu_devices()
        .into_iter()
        .next()
        .map(|(_, d)| d)
        .expect("no CPU backend compiled in: enable the `flex` or `ndarray` feature")
}

/// A module built by `build` on the CPU (autodiff on) seeded with `seed`, its parameters drawn
/// there in visiting order, then moved to `device`. Each backend draws its own random numbers
/// from a seed, and Burn draws a parameter on its first use (a lazy parameter moved to another
/// device is drawn there), so this is what gives the same initial weights on every device.
pub fn init_seeded<M: Module, E>(
    seed: u64,
    device: &Device,
    build: impl FnOnce(&Device) -> Result<M, E>,
) -> Result<M, E> {
    let cpu = cpu().autodiff();
    cpu.seed(seed);
    let module = build(&cpu)?;
    crate::params::initialise_all(&module);
    Ok(module.fork(device))
}

/// The environment variable that points the backend-generic tests at a device (`cpu` when unset).
pub const TEST_DEVICE_VAR: &str = "NEUROFLUID_TEST_DEVICE";

/// The device name the backend-generic tests run on: `$NEUROFLUID_TEST_DEVICE`, else `cpu`.
pub fn test_device_name() -> String {
    device_name_or_cpu(std::env::var(TEST_DEVICE_VAR).ok().as_deref())
}

/// A device name as given, trimmed; `cpu` when absent or blank.
fn device_name_or_cpu(name: Option<&str>) -> String {
    match name.map(str::trim) {
        Some(n) if !n.is_empty() => n.to_string(),
        _ => "cpu".into(),
    }
}

/// The device the backend-generic tests run on (see [`test_device_name`]).
///
/// # Panics
/// When the variable names a device this build cannot make: the message names the variable and
/// the cargo feature to enable (a test-setup error, not user input).
pub fn test_device() -> Device {
    let name = test_device_name();
    parse_device(&name).unwrap_or_else(|e| panic!("{TEST_DEVICE_VAR}={name}: {e}"))
}

/// The names of the wgpu device.
const WGPU_NAMES: [&str; 2] = ["wgpu", "gpu"];

/// Whether float64 computes correctly on the device named `name` (a [`parse_device`] name): the
/// device has the type, and it is not wgpu. WGSL and Vulkan's SPIR-V define `exp`, `log`, `sin`
/// and `cos` for 16- and 32-bit floats only; cubecl emits them for f64 anyway, and drivers such
/// as Mesa's run them as garbage (cubecl issue 1316; on lavapipe PhysNeRF's float64 weights
/// were off by up to 1). The float64 checks (finite differences, the f64 parity case) need
/// this; training runs in float32.
pub fn float64_supported(name: &str) -> bool {
    !is_wgpu_name(name)
        && parse_device(name).is_ok_and(|d| d.supports_dtype(burn::tensor::DType::F64))
}

/// Whether `name` (a [`parse_device`] name) names the wgpu device.
pub fn is_wgpu_name(name: &str) -> bool {
    WGPU_NAMES.contains(&name.trim().to_ascii_lowercase().as_str())
}

/// [`float64_supported`] for the device the backend-generic tests run on.
pub fn test_device_has_float64() -> bool {
    float64_supported(&test_device_name())
}

/// Turns a device name into a device: `cpu` (flex, else ndarray), `flex`, `ndarray`, `wgpu`,
/// `cuda` or `cuda:N`. Names are case-insensitive.
pub fn parse_device(name: &str) -> Result<Device, DeviceError> {
    let lower = name.trim().to_ascii_lowercase();
    let not_compiled = |feature| DeviceError::NotCompiled {
        name: name.to_string(),
        feature,
    };
    match lower.as_str() {
        "cpu" => cpu_devices()
            .into_iter()
            .next()
            .map(|(_, d)| d)
            .ok_or_else(|| not_compiled("flex")),
        "flex" => flex().ok_or_else(|| not_compiled("flex")),
        "ndarray" => ndarray().ok_or_else(|| not_compiled("ndarray")),
        n if WGPU_NAMES.contains(&n) => wgpu().ok_or_else(|| not_compiled("wgpu")),
        _ => {
            if let Some(index) = lower.strip_prefix("cuda").and_then(parse_index) {
                return cuda(index).ok_or_else(|| not_compiled("cuda"));
            }
            Err(DeviceError::Unknown {
                name: name.to_string(),
            })
        }
    }
}

/// `""` → 0, `":N"` → N.
fn parse_index(rest: &str) -> Option<usize> {
    if rest.is_empty() {
        return Some(0);
    }
    rest.strip_prefix(':')?.parse().ok()
}

fn flex() -> Option<Device> {
    #[cfg(feature = "flex")]
    return Some(Device::flex());
    #[cfg(not(feature = "flex"))]
    None
}

fn ndarray() -> Option<Device> {
    #[cfg(feature = "ndarray")]
    #[allow(deprecated)]
    return Some(Device::ndarray());
    #[cfg(not(feature = "ndarray"))]
    None
}

/// The tensor-core (cooperative-matrix) shapes the wgpu device offers its matmuls, as
/// `a×b→c m×n×k` (e.g. `f16×f16→f32 16×16×16`), sorted; `None` where wgpu is not compiled in.
/// An empty list: every matmul runs on the scalar kernel.
pub fn wgpu_tensor_core_shapes() -> Option<Vec<String>> {
    #[cfg(feature = "wgpu-base")]
    {
        let client = cubecl::Device::Wgpu(burn::backend::wgpu::WgpuDevice::default()).client();
        let shapes = client.properties().features.matmul.cmma.iter().map(|c| {
            format!(
                "{}×{}→{} {}×{}×{}",
                c.a_type, c.b_type, c.cd_type, c.m, c.n, c.k
            )
        });
        Some(shapes.collect())
    }
    #[cfg(not(feature = "wgpu-base"))]
    None
}

fn wgpu() -> Option<Device> {
    #[cfg(feature = "wgpu-base")]
    return Some(Device::wgpu(burn::prelude::DeviceKind::DefaultDevice));
    #[cfg(not(feature = "wgpu-base"))]
    None
}

fn cuda(index: usize) -> Option<Device> {
    #[cfg(feature = "cuda")]
    return Some(Device::cuda(index));
    #[cfg(not(feature = "cuda"))]
    {
        let _ = index;
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_names_are_rejected_with_the_choices() {
        let err = parse_device("tpu").unwrap_err();
        assert_eq!(err, DeviceError::Unknown { name: "tpu".into() });
        assert!(err.to_string().contains("cpu, flex, ndarray, wgpu, cuda"));
        assert!(parse_device("cuda:x").is_err());
    }

    #[test]
    fn missing_backends_name_their_feature() {
        for (name, feature) in [("wgpu", "wgpu"), ("cuda:1", "cuda"), ("ndarray", "ndarray")] {
            if compiled_backends().contains(&feature) {
                continue;
            }
            let err = parse_device(name).unwrap_err();
            assert!(
                err.to_string().contains(&format!("--features {feature}")),
                "{err}"
            );
        }
    }

    #[test]
    fn the_test_device_defaults_to_the_cpu() {
        assert_eq!(device_name_or_cpu(None), "cpu");
        assert_eq!(device_name_or_cpu(Some("  ")), "cpu");
        assert_eq!(device_name_or_cpu(Some(" wgpu\n")), "wgpu");
    }

    #[test]
    fn float64_is_refused_on_wgpu_only() {
        assert!(!float64_supported("wgpu"));
        assert!(!float64_supported(" GPU"));
        assert!(!float64_supported("tpu"));
        assert_eq!(
            float64_supported("cpu"),
            cpu().supports_dtype(burn::tensor::DType::F64)
        );
    }

    #[test]
    fn the_cpu_backends_are_the_host_with_or_without_autodiff() {
        for (_, d) in cpu_devices() {
            assert!(is_host(&d) && is_host(&d.clone().autodiff()));
        }
        if let Some(gpu) = wgpu() {
            assert!(!is_host(&gpu) && !is_host(&gpu.autodiff()));
        }
    }

    #[test]
    fn cpu_is_always_available() {
        assert!(parse_device("CPU").is_ok());
        assert!(!cpu_devices().is_empty());
    }
}
