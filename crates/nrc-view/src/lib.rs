//! `nrc view`: the online loop live in a window. Produce → train → render the chosen pass →
//! display, with progressive accumulation while camera and scene stand still, fly controls,
//! panels for the loop's settings, debug views (the cache at the first vertex, the raw pass
//! output, where the frame's training records landed, the error against a reference, the
//! pass's own state) and plots of the loss and the frame time by phase.
//!
//! The loop runs on its own thread ([`session`]) at its own rate; the window (winit, a wgpu
//! surface, egui through egui-wgpu) shows its last finished frame at up to 60 UI frames a
//! second ([`window`]). The display shaders (tone mapping, false colour, heat map) are WGSL in
//! `shaders/view.wgsl` ([`display`]). The headless mode ([`headless`]) runs the same loop and
//! paints the same UI offscreen: for tests and documentation pictures.

pub mod camera;
pub mod canvas;
pub mod display;
pub mod headless;
pub mod session;
pub mod ui;
pub mod window;

pub use headless::{HeadlessOptions, HeadlessReport, run_headless};
pub use session::{Animation, Command, LoopSetup, Published, Session, View};
pub use window::{WindowOptions, run_window};

/// Why the viewer cannot run.
#[derive(Debug, thiserror::Error)]
pub enum ViewError {
    /// No window system to open a window on.
    #[error("cannot open a window: {0} (is there a display? `nrc view --headless` needs none)")]
    NoDisplay(String),
    /// No adapter to draw with.
    #[error("no GPU adapter to draw with: {0}")]
    NoAdapter(String),
    #[error("GPU: {0}")]
    Gpu(String),
    /// An output file could not be written.
    #[error("cannot write {0}: {1}")]
    Output(String, String),
    /// A frame of the loop failed.
    #[error("{0}")]
    Loop(String),
    /// A bad option.
    #[error("{0}")]
    Option(String),
}
