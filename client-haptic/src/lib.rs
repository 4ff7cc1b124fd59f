//! cathlab's haptic-device bridge: the UDP device protocol, the coupling law, the bridge
//! runtime (control stream + 1 kHz loop) and a scripted virtual device.

pub mod bridge;
pub mod coupling;
pub mod device;
pub mod protocol;
