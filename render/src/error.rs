//! What can go wrong while rendering.

/// A renderer error. Messages are one line and say what to do where the user can act.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// No graphics adapter on this machine (no GPU driver and no software rasteriser).
    #[error(
        "no graphics adapter for the renderer ({0}): install Mesa's Vulkan software rasteriser \
         (package mesa-vulkan-drivers; run 'bash scripts/setup.sh') or a GPU driver"
    )]
    NoAdapter(String),
    /// The adapter refused a device with the limits the renderer needs.
    #[error("the graphics adapter '{adapter}' refused a device: {message}")]
    Device {
        /// The adapter's name.
        adapter: String,
        /// wgpu's reason.
        message: String,
    },
    /// A camera cannot be rendered as specified.
    #[error("camera '{name}': {message}")]
    Camera {
        /// The camera's name.
        name: String,
        /// What is wrong.
        message: String,
    },
    /// No camera at this index.
    #[error("no camera {index} (the renderer has {count})")]
    NoCamera {
        /// The index asked for.
        index: usize,
        /// How many cameras there are.
        count: usize,
    },
    /// A scene shape cannot be drawn.
    #[error("scene object {index}: {message}")]
    Shape {
        /// Index of the object in the scene.
        index: usize,
        /// What is wrong.
        message: String,
    },
    /// The state handed to the renderer does not match the vehicle or the scene it was built for.
    #[error("state does not match the renderer: {0}")]
    State(String),
    /// Reading the rendered image back from the adapter failed.
    #[error("reading the frame back failed: {0}")]
    Readback(String),
    /// Encoding a PNG failed.
    #[error("PNG encoding failed: {0}")]
    Png(String),
}
