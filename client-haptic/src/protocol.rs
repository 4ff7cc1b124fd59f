//! The UDP protocol between a haptic device's driver process and the bridge: fixed-size
//! little-endian datagrams, one per device tick in each direction.
//!
//! Device → bridge, [`DeviceSample`] (40 bytes):
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | `[u8; 4]` | magic `CLHD` |
//! | 4 | u8 | version (1) |
//! | 5 | u8 | buttons: bit 0 fluoroscopy pedal, bit 1 reset |
//! | 6 | u16 | reserved (0) |
//! | 8 | u32 | sequence number (wraps) |
//! | 12 | u32 | reserved (0) |
//! | 16 | u64 | device clock (µs), echoed back |
//! | 24 | f64 | insertion position (mm, + forward, any zero) |
//! | 32 | f64 | rotation angle (deg, + clockwise seen from the operator, unwrapped) |
//!
//! Bridge → device, [`Feedback`] (40 bytes):
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | `[u8; 4]` | magic `CLHF` |
//! | 4 | u8 | version (1) |
//! | 5 | u8 | status: bit 0 session connected, bit 1 feedback live (server state fresh) |
//! | 6 | u16 | reserved (0) |
//! | 8 | u32 | sequence number of the last device sample received |
//! | 12 | u32 | age of the server state behind this feedback (µs, saturating) |
//! | 16 | u64 | device clock of that sample (µs), for the device's round-trip time |
//! | 24 | f64 | force to render along the insertion axis (N, + pushes the hand back) |
//! | 32 | f64 | torque to render about the axis (N·mm, + resists clockwise turning) |
//!
//! Datagrams of any other length, magic or version, or with non-finite numbers, are
//! rejected with a [`ProtocolError`] naming what was wrong.

/// Bytes in either datagram.
pub const DATAGRAM_BYTES: usize = 40;
/// Protocol version.
pub const VERSION: u8 = 1;
const DEVICE_MAGIC: [u8; 4] = *b"CLHD";
const FEEDBACK_MAGIC: [u8; 4] = *b"CLHF";

/// Why a datagram was rejected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ProtocolError {
    /// Wrong size.
    #[error("datagram of {0} bytes; the protocol's are {DATAGRAM_BYTES}")]
    Length(usize),
    /// Not this protocol.
    #[error("bad magic {0:?}")]
    Magic([u8; 4]),
    /// Another version.
    #[error("protocol version {0}; this bridge speaks {VERSION}")]
    Version(u8),
    /// NaN or infinite.
    #[error("{0} is not finite")]
    NotFinite(&'static str),
}

/// One device reading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceSample {
    /// Sequence number.
    pub seq: u32,
    /// Device clock (µs).
    pub device_time_us: u64,
    /// Insertion position (mm).
    pub insertion_mm: f64,
    /// Rotation angle (deg).
    pub rotation_deg: f64,
    /// Fluoroscopy pedal down.
    pub pedal: bool,
    /// Reset button down.
    pub reset: bool,
}

/// One force/torque command for the device.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Feedback {
    /// Sequence number of the last device sample.
    pub seq: u32,
    /// Device clock of that sample (µs).
    pub device_time_us: u64,
    /// Age of the server state used (µs).
    pub state_age_us: u32,
    /// Connected to a session.
    pub connected: bool,
    /// The server state is fresh enough to render.
    pub live: bool,
    /// Axial force (N).
    pub force_n: f64,
    /// Torque about the axis (N·mm).
    pub torque_nmm: f64,
}

fn header(bytes: &[u8], magic: [u8; 4]) -> Result<(), ProtocolError> {
    if bytes.len() != DATAGRAM_BYTES {
        return Err(ProtocolError::Length(bytes.len()));
    }
    let got: [u8; 4] = bytes[0..4].try_into().expect("4 bytes");
    if got != magic {
        return Err(ProtocolError::Magic(got));
    }
    if bytes[4] != VERSION {
        return Err(ProtocolError::Version(bytes[4]));
    }
    Ok(())
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"))
}
fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"))
}
fn f64_at(b: &[u8], at: usize, name: &'static str) -> Result<f64, ProtocolError> {
    let v = f64::from_le_bytes(b[at..at + 8].try_into().expect("8 bytes"));
    if v.is_finite() {
        Ok(v)
    } else {
        Err(ProtocolError::NotFinite(name))
    }
}

impl DeviceSample {
    /// Encodes the datagram.
    pub fn encode(&self) -> [u8; DATAGRAM_BYTES] {
        let mut b = [0u8; DATAGRAM_BYTES];
        b[0..4].copy_from_slice(&DEVICE_MAGIC);
        b[4] = VERSION;
        b[5] = u8::from(self.pedal) | (u8::from(self.reset) << 1);
        b[8..12].copy_from_slice(&self.seq.to_le_bytes());
        b[16..24].copy_from_slice(&self.device_time_us.to_le_bytes());
        b[24..32].copy_from_slice(&self.insertion_mm.to_le_bytes());
        b[32..40].copy_from_slice(&self.rotation_deg.to_le_bytes());
        b
    }

    /// Decodes a datagram.
    pub fn decode(b: &[u8]) -> Result<Self, ProtocolError> {
        header(b, DEVICE_MAGIC)?;
        Ok(Self {
            seq: u32_at(b, 8),
            device_time_us: u64_at(b, 16),
            insertion_mm: f64_at(b, 24, "insertion position")?,
            rotation_deg: f64_at(b, 32, "rotation angle")?,
            pedal: b[5] & 1 != 0,
            reset: b[5] & 2 != 0,
        })
    }
}

impl Feedback {
    /// Encodes the datagram.
    pub fn encode(&self) -> [u8; DATAGRAM_BYTES] {
        let mut b = [0u8; DATAGRAM_BYTES];
        b[0..4].copy_from_slice(&FEEDBACK_MAGIC);
        b[4] = VERSION;
        b[5] = u8::from(self.connected) | (u8::from(self.live) << 1);
        b[8..12].copy_from_slice(&self.seq.to_le_bytes());
        b[12..16].copy_from_slice(&self.state_age_us.to_le_bytes());
        b[16..24].copy_from_slice(&self.device_time_us.to_le_bytes());
        b[24..32].copy_from_slice(&self.force_n.to_le_bytes());
        b[32..40].copy_from_slice(&self.torque_nmm.to_le_bytes());
        b
    }

    /// Decodes a datagram.
    pub fn decode(b: &[u8]) -> Result<Self, ProtocolError> {
        header(b, FEEDBACK_MAGIC)?;
        Ok(Self {
            seq: u32_at(b, 8),
            state_age_us: u32_at(b, 12),
            device_time_us: u64_at(b, 16),
            force_n: f64_at(b, 24, "force")?,
            torque_nmm: f64_at(b, 32, "torque")?,
            connected: b[5] & 1 != 0,
            live: b[5] & 2 != 0,
        })
    }
}

/// Samples lost between two sequence numbers (wrapping), 0 for in-order or repeated ones.
pub fn lost_between(previous: u32, next: u32) -> u32 {
    let gap = next.wrapping_sub(previous);
    if gap == 0 || gap > u32::MAX / 2 {
        0
    } else {
        gap - 1
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn datagrams_round_trip(seq in any::<u32>(), t in any::<u64>(), x in -1e4f64..1e4, a in -1e6f64..1e6, buttons in 0u8..4) {
            let s = DeviceSample { seq, device_time_us: t, insertion_mm: x, rotation_deg: a, pedal: buttons & 1 != 0, reset: buttons & 2 != 0 };
            prop_assert_eq!(DeviceSample::decode(&s.encode()).unwrap(), s);
            let f = Feedback { seq, device_time_us: t, state_age_us: seq / 3, connected: buttons & 1 != 0, live: buttons & 2 != 0, force_n: x, torque_nmm: a };
            prop_assert_eq!(Feedback::decode(&f.encode()).unwrap(), f);
        }
    }

    #[test]
    fn the_layout_is_the_documented_one() {
        let s = DeviceSample {
            seq: 0x0102_0304,
            device_time_us: 7,
            insertion_mm: 1.5,
            rotation_deg: -2.0,
            pedal: true,
            reset: false,
        };
        let b = s.encode();
        assert_eq!(&b[0..4], b"CLHD");
        assert_eq!(b[4], 1);
        assert_eq!(b[5], 1);
        assert_eq!(&b[8..12], &[4, 3, 2, 1]);
        assert_eq!(&b[16..24], &7u64.to_le_bytes());
        assert_eq!(&b[24..32], &1.5f64.to_le_bytes());
        assert_eq!(&b[32..40], &(-2.0f64).to_le_bytes());
    }

    #[test]
    fn bad_datagrams_are_named() {
        let good = DeviceSample {
            seq: 1,
            device_time_us: 0,
            insertion_mm: 0.0,
            rotation_deg: 0.0,
            pedal: false,
            reset: false,
        }
        .encode();
        assert_eq!(
            DeviceSample::decode(&good[..39]),
            Err(ProtocolError::Length(39))
        );
        let mut magic = good;
        magic[0] = b'X';
        assert!(matches!(
            DeviceSample::decode(&magic),
            Err(ProtocolError::Magic(_))
        ));
        assert!(matches!(
            Feedback::decode(&good),
            Err(ProtocolError::Magic(_))
        ));
        let mut version = good;
        version[4] = 9;
        assert_eq!(
            DeviceSample::decode(&version),
            Err(ProtocolError::Version(9))
        );
        let mut nan = good;
        nan[24..32].copy_from_slice(&f64::NAN.to_le_bytes());
        let err = DeviceSample::decode(&nan).unwrap_err();
        assert_eq!(err, ProtocolError::NotFinite("insertion position"));
        assert!(err.to_string().contains("insertion position"));
    }

    #[test]
    fn lost_samples_count_across_the_wrap() {
        assert_eq!(lost_between(1, 2), 0);
        assert_eq!(lost_between(1, 5), 3);
        assert_eq!(lost_between(u32::MAX, 1), 1);
        assert_eq!(lost_between(5, 5), 0);
        assert_eq!(lost_between(5, 3), 0, "reordered, not lost");
    }
}
