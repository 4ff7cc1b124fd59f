//! The UDP protocol between a haptic device's driver process and the bridge: fixed-size
//! little-endian datagrams, one per device tick in each direction. Version 1 carries one
//! instrument channel; version 2 adds a second, for a device with two hands (the outer
//! instrument, e.g. the catheter hub, beside the inner one, e.g. the wire's torquer). The
//! bridge answers each device in the version it speaks, so a one-channel device still works.
//!
//! Device → bridge, [`DeviceSample`] (40 bytes in version 1, 56 in version 2):
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | `[u8; 4]` | magic `CLHD` |
//! | 4 | u8 | version (1 or 2) |
//! | 5 | u8 | buttons: bit 0 fluoroscopy pedal, bit 1 reset |
//! | 6 | u16 | reserved (0) |
//! | 8 | u32 | sequence number (wraps) |
//! | 12 | u32 | reserved (0) |
//! | 16 | u64 | device clock (µs), echoed back |
//! | 24 | f64 | insertion position (mm, + forward, any zero): the inner (or only) instrument |
//! | 32 | f64 | rotation angle (deg, + clockwise seen from the operator, unwrapped): the same |
//! | 40 | f64 | version 2: the outer instrument's insertion position (mm) |
//! | 48 | f64 | version 2: the outer instrument's rotation angle (deg) |
//!
//! Bridge → device, [`Feedback`] (40 bytes in version 1, 56 in version 2):
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | `[u8; 4]` | magic `CLHF` |
//! | 4 | u8 | version (that of the device's samples) |
//! | 5 | u8 | status: bit 0 session connected, bit 1 feedback live (server state fresh), bit 2 (version 2) the outer channel's feedback live (the scene has an outer instrument) |
//! | 6 | u16 | reserved (0) |
//! | 8 | u32 | sequence number of the last device sample received |
//! | 12 | u32 | age of the server state behind this feedback (µs, saturating) |
//! | 16 | u64 | device clock of that sample (µs), for the device's round-trip time |
//! | 24 | f64 | force to render along the insertion axis (N, + pushes the hand back): inner instrument |
//! | 32 | f64 | torque to render about the axis (N·mm, + resists clockwise turning): inner instrument |
//! | 40 | f64 | version 2: the outer instrument's force (N) |
//! | 48 | f64 | version 2: the outer instrument's torque (N·mm) |
//!
//! Datagrams of any other length, magic or version, or with non-finite numbers, are
//! rejected with a [`ProtocolError`] naming what was wrong.

use std::ops::Deref;

/// Bytes in a version 1 datagram (either direction).
pub const DATAGRAM_BYTES: usize = 40;
/// Bytes in a version 2 (two-channel) datagram.
pub const DATAGRAM_V2_BYTES: usize = 56;
/// The newest protocol version.
pub const VERSION: u8 = 2;
const DEVICE_MAGIC: [u8; 4] = *b"CLHD";
const FEEDBACK_MAGIC: [u8; 4] = *b"CLHF";

/// Why a datagram was rejected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ProtocolError {
    /// Wrong size for its version.
    #[error("datagram of {got} bytes; protocol version {version}'s are {expected}")]
    Length {
        /// Bytes received.
        got: usize,
        /// The version its header names (or 1 when too short to have one).
        version: u8,
        /// That version's size.
        expected: usize,
    },
    /// Not this protocol.
    #[error("bad magic {0:?}")]
    Magic([u8; 4]),
    /// Another version.
    #[error("protocol version {0}; this bridge speaks 1 and {VERSION}")]
    Version(u8),
    /// NaN or infinite.
    #[error("{0} is not finite")]
    NotFinite(&'static str),
}

/// One channel's position: where a hand holds its instrument.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct HandPosition {
    /// Insertion position (mm).
    pub insertion_mm: f64,
    /// Rotation angle (deg).
    pub rotation_deg: f64,
}

/// One channel's feedback: what a hand feels.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct HandFeedback {
    /// Axial force (N).
    pub force_n: f64,
    /// Torque about the axis (N·mm).
    pub torque_nmm: f64,
    /// The server state behind it was fresh and the instrument exists.
    pub live: bool,
}

/// One device reading.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceSample {
    /// Sequence number.
    pub seq: u32,
    /// Device clock (µs).
    pub device_time_us: u64,
    /// Insertion position of the inner (or only) instrument (mm).
    pub insertion_mm: f64,
    /// Rotation angle of the inner (or only) instrument (deg).
    pub rotation_deg: f64,
    /// Fluoroscopy pedal down.
    pub pedal: bool,
    /// Reset button down.
    pub reset: bool,
    /// A two-hand device's outer channel (version 2); `None` for a one-channel device.
    pub outer: Option<HandPosition>,
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
    /// Axial force, inner (or only) instrument (N).
    pub force_n: f64,
    /// Torque about the axis, inner (or only) instrument (N·mm).
    pub torque_nmm: f64,
    /// The outer channel (version 2, answering a two-channel device).
    pub outer: Option<HandFeedback>,
}

/// An encoded datagram (40 or 56 bytes), without allocating.
#[derive(Debug, Clone, Copy)]
pub struct Datagram {
    bytes: [u8; DATAGRAM_V2_BYTES],
    len: usize,
}

impl Deref for Datagram {
    type Target = [u8];
    fn deref(&self) -> &[u8] {
        &self.bytes[..self.len]
    }
}

/// Checks the header; returns the version (1: one channel, 2: two).
fn header(bytes: &[u8], magic: [u8; 4]) -> Result<u8, ProtocolError> {
    if bytes.len() < 5 {
        return Err(ProtocolError::Length {
            got: bytes.len(),
            version: 1,
            expected: DATAGRAM_BYTES,
        });
    }
    let got: [u8; 4] = bytes[0..4].try_into().expect("4 bytes");
    if got != magic {
        return Err(ProtocolError::Magic(got));
    }
    let expected = match bytes[4] {
        1 => DATAGRAM_BYTES,
        2 => DATAGRAM_V2_BYTES,
        v => return Err(ProtocolError::Version(v)),
    };
    if bytes.len() != expected {
        return Err(ProtocolError::Length {
            got: bytes.len(),
            version: bytes[4],
            expected,
        });
    }
    Ok(bytes[4])
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

/// A datagram's common start: magic, version, flags, sequence number, a u32 and the clock.
fn start(magic: [u8; 4], two: bool, flags: u8, seq: u32, word: u32, clock_us: u64) -> Datagram {
    let mut b = [0u8; DATAGRAM_V2_BYTES];
    b[0..4].copy_from_slice(&magic);
    b[4] = if two { 2 } else { 1 };
    b[5] = flags;
    b[8..12].copy_from_slice(&seq.to_le_bytes());
    b[12..16].copy_from_slice(&word.to_le_bytes());
    b[16..24].copy_from_slice(&clock_us.to_le_bytes());
    Datagram {
        bytes: b,
        len: if two {
            DATAGRAM_V2_BYTES
        } else {
            DATAGRAM_BYTES
        },
    }
}

/// Writes a channel's two numbers at `at` and `at + 8`.
fn put_pair(d: &mut Datagram, at: usize, a: f64, b: f64) {
    d.bytes[at..at + 8].copy_from_slice(&a.to_le_bytes());
    d.bytes[at + 8..at + 16].copy_from_slice(&b.to_le_bytes());
}

impl DeviceSample {
    /// Encodes the datagram: version 2 with an outer channel, else version 1.
    pub fn encode(&self) -> Datagram {
        let flags = u8::from(self.pedal) | (u8::from(self.reset) << 1);
        let mut d = start(
            DEVICE_MAGIC,
            self.outer.is_some(),
            flags,
            self.seq,
            0,
            self.device_time_us,
        );
        put_pair(&mut d, 24, self.insertion_mm, self.rotation_deg);
        if let Some(o) = self.outer {
            put_pair(&mut d, 40, o.insertion_mm, o.rotation_deg);
        }
        d
    }

    /// Decodes a datagram of either version.
    pub fn decode(b: &[u8]) -> Result<Self, ProtocolError> {
        let version = header(b, DEVICE_MAGIC)?;
        Ok(Self {
            seq: u32_at(b, 8),
            device_time_us: u64_at(b, 16),
            insertion_mm: f64_at(b, 24, "insertion position")?,
            rotation_deg: f64_at(b, 32, "rotation angle")?,
            pedal: b[5] & 1 != 0,
            reset: b[5] & 2 != 0,
            outer: if version == 2 {
                Some(HandPosition {
                    insertion_mm: f64_at(b, 40, "outer insertion position")?,
                    rotation_deg: f64_at(b, 48, "outer rotation angle")?,
                })
            } else {
                None
            },
        })
    }
}

impl Feedback {
    /// Encodes the datagram: version 2 with an outer channel, else version 1.
    pub fn encode(&self) -> Datagram {
        let outer_live = self.outer.is_some_and(|o| o.live);
        let flags =
            u8::from(self.connected) | (u8::from(self.live) << 1) | (u8::from(outer_live) << 2);
        let mut d = start(
            FEEDBACK_MAGIC,
            self.outer.is_some(),
            flags,
            self.seq,
            self.state_age_us,
            self.device_time_us,
        );
        put_pair(&mut d, 24, self.force_n, self.torque_nmm);
        if let Some(o) = self.outer {
            put_pair(&mut d, 40, o.force_n, o.torque_nmm);
        }
        d
    }

    /// Decodes a datagram of either version.
    pub fn decode(b: &[u8]) -> Result<Self, ProtocolError> {
        let version = header(b, FEEDBACK_MAGIC)?;
        Ok(Self {
            seq: u32_at(b, 8),
            state_age_us: u32_at(b, 12),
            device_time_us: u64_at(b, 16),
            force_n: f64_at(b, 24, "force")?,
            torque_nmm: f64_at(b, 32, "torque")?,
            connected: b[5] & 1 != 0,
            live: b[5] & 2 != 0,
            outer: if version == 2 {
                Some(HandFeedback {
                    force_n: f64_at(b, 40, "outer force")?,
                    torque_nmm: f64_at(b, 48, "outer torque")?,
                    live: b[5] & 4 != 0,
                })
            } else {
                None
            },
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

    fn sample(outer: Option<HandPosition>) -> DeviceSample {
        DeviceSample {
            seq: 1,
            device_time_us: 0,
            insertion_mm: 0.0,
            rotation_deg: 0.0,
            pedal: false,
            reset: false,
            outer,
        }
    }

    proptest! {
        #[test]
        fn datagrams_round_trip(seq in any::<u32>(), t in any::<u64>(), x in -1e4f64..1e4, a in -1e6f64..1e6, buttons in 0u8..8, two in any::<bool>()) {
            let outer = two.then_some(HandPosition { insertion_mm: a / 7.0, rotation_deg: x * 3.0 });
            let s = DeviceSample { seq, device_time_us: t, insertion_mm: x, rotation_deg: a, pedal: buttons & 1 != 0, reset: buttons & 2 != 0, outer };
            let d = s.encode();
            prop_assert_eq!(d.len(), if two { DATAGRAM_V2_BYTES } else { DATAGRAM_BYTES });
            prop_assert_eq!(DeviceSample::decode(&d).unwrap(), s);
            let outer = two.then_some(HandFeedback { force_n: -x, torque_nmm: a / 3.0, live: buttons & 4 != 0 });
            let f = Feedback { seq, device_time_us: t, state_age_us: seq / 3, connected: buttons & 1 != 0, live: buttons & 2 != 0, force_n: x, torque_nmm: a, outer };
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
            outer: None,
        };
        let b = s.encode();
        assert_eq!(b.len(), 40);
        assert_eq!(&b[0..4], b"CLHD");
        assert_eq!(b[4], 1);
        assert_eq!(b[5], 1);
        assert_eq!(&b[8..12], &[4, 3, 2, 1]);
        assert_eq!(&b[16..24], &7u64.to_le_bytes());
        assert_eq!(&b[24..32], &1.5f64.to_le_bytes());
        assert_eq!(&b[32..40], &(-2.0f64).to_le_bytes());
        // Version 2 is version 1 with the outer channel appended.
        let two = DeviceSample {
            outer: Some(HandPosition {
                insertion_mm: 3.25,
                rotation_deg: 45.0,
            }),
            ..s
        }
        .encode();
        assert_eq!(two.len(), 56);
        assert_eq!(two[4], 2);
        assert_eq!(&two[5..40], &b[5..40]);
        assert_eq!(&two[40..48], &3.25f64.to_le_bytes());
        assert_eq!(&two[48..56], &45.0f64.to_le_bytes());
        let f = Feedback {
            outer: Some(HandFeedback {
                force_n: 0.5,
                torque_nmm: -1.0,
                live: true,
            }),
            ..Feedback::default()
        }
        .encode();
        assert_eq!((&f[0..4], f[4], f[5]), (&b"CLHF"[..], 2, 4));
        assert_eq!(&f[40..48], &0.5f64.to_le_bytes());
    }

    #[test]
    fn bad_datagrams_are_named() {
        let good = sample(None).encode();
        assert_eq!(
            DeviceSample::decode(&good[..39]),
            Err(ProtocolError::Length {
                got: 39,
                version: 1,
                expected: 40
            })
        );
        assert!(DeviceSample::decode(&good[..3]).is_err());
        let mut magic = *good.deref().first_chunk::<40>().unwrap();
        magic[0] = b'X';
        assert!(matches!(
            DeviceSample::decode(&magic),
            Err(ProtocolError::Magic(_))
        ));
        assert!(matches!(
            Feedback::decode(&good),
            Err(ProtocolError::Magic(_))
        ));
        let mut version = *good.deref().first_chunk::<40>().unwrap();
        version[4] = 9;
        assert_eq!(
            DeviceSample::decode(&version),
            Err(ProtocolError::Version(9))
        );
        let mut nan = *good.deref().first_chunk::<40>().unwrap();
        nan[24..32].copy_from_slice(&f64::NAN.to_le_bytes());
        let err = DeviceSample::decode(&nan).unwrap_err();
        assert_eq!(err, ProtocolError::NotFinite("insertion position"));
        assert!(err.to_string().contains("insertion position"));
    }

    #[test]
    fn malformed_two_channel_datagrams_are_named() {
        let two = sample(Some(HandPosition::default())).encode();
        let mut bytes = *two.deref().first_chunk::<56>().unwrap();
        // A version 2 header on a version 1 length (a one-channel body) and the reverse.
        let short = DeviceSample::decode(&bytes[..40]).unwrap_err();
        assert_eq!(
            short,
            ProtocolError::Length {
                got: 40,
                version: 2,
                expected: 56
            }
        );
        assert!(short.to_string().contains("version 2's are 56"), "{short}");
        let mut long = [0u8; 56];
        long.copy_from_slice(&bytes);
        long[4] = 1;
        assert!(matches!(
            DeviceSample::decode(&long),
            Err(ProtocolError::Length {
                got: 56,
                version: 1,
                ..
            })
        ));
        // The outer channel's numbers are checked and named.
        bytes[40..48].copy_from_slice(&f64::INFINITY.to_le_bytes());
        let err = DeviceSample::decode(&bytes).unwrap_err();
        assert_eq!(err, ProtocolError::NotFinite("outer insertion position"));
        bytes[40..48].copy_from_slice(&0f64.to_le_bytes());
        bytes[48..56].copy_from_slice(&f64::NAN.to_le_bytes());
        assert_eq!(
            DeviceSample::decode(&bytes).unwrap_err().to_string(),
            "outer rotation angle is not finite"
        );
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
