//! MAVLink frames written by hand, so that a mutated payload, header or signature still gets
//! a valid CRC (or a chosen wrong one): structure-aware mutations must reach the message
//! parser and the decoder, not die at the CRC check.

use mavlink::dialects::ardupilotmega as apm;
use mavlink::{MAVLinkV2MessageRaw, MavlinkVersion, Message};

/// MAVLink 2 signing key used by the signed link modes.
pub const SIGNING_KEY: [u8; 32] = *b"ianav-fuzz-signing-key-32-bytes!";
/// Base of the signature timestamps (10 µs since 2015-01-01). It lies in 2059: the mavlink
/// crate refuses a new stream whose timestamp is more than a minute behind the wall clock, and
/// a timestamp ahead of it keeps acceptance independent of when the fuzzer runs.
pub const SIGNATURE_TS_BASE: u64 = 1 << 47;

/// Incompatibility flag: signed frame.
pub const IFLAG_SIGNED: u8 = 0x01;
/// Incompatibility flag: 32-bit system id.
pub const IFLAG_SYSID32: u8 = 0x02;

/// Signature of a MAVLink 2 frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Signature {
    /// Link id.
    pub link_id: u8,
    /// Timestamp, 48 bits used.
    pub timestamp: u64,
    /// Key to sign with (a wrong key gives a bad signature).
    pub key: [u8; 32],
}

/// One frame before encoding. The payload is kept untrimmed so that any field can be patched.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FrameSpec {
    /// Protocol version.
    pub version: MavlinkVersion,
    /// Sequence number.
    pub seq: u8,
    /// System id (above 255: MAVLink 2 with the 32-bit system id flag; truncated in v1).
    pub sys: u32,
    /// Component id.
    pub comp: u8,
    /// Message id (truncated to 8 bits in v1, 24 bits in v2).
    pub msg_id: u32,
    /// Payload (v2 trailing zeros are trimmed on encoding, as senders do).
    pub payload: Vec<u8>,
    /// Extra incompatibility flags set (unknown ones make the frame invalid).
    pub extra_iflags: u8,
    /// Compatibility flags.
    pub compat: u8,
    /// Signature (v2 only).
    pub signature: Option<Signature>,
    /// XOR applied to the CRC (0: valid).
    pub crc_xor: u16,
}

impl FrameSpec {
    /// A valid frame of `msg` from (`sys`, `comp`).
    pub fn of(msg: &apm::MavMessage, version: MavlinkVersion, sys: u32, comp: u8, seq: u8) -> Self {
        let mut buf = [0_u8; 255];
        let n = msg.ser(version, &mut buf);
        Self {
            version,
            seq,
            sys,
            comp,
            msg_id: msg.message_id(),
            payload: buf[..n].to_vec(),
            extra_iflags: 0,
            compat: 0,
            signature: None,
            crc_xor: 0,
        }
    }

    /// The frame's bytes.
    pub fn encode(&self) -> Vec<u8> {
        match self.version {
            MavlinkVersion::V1 => self.encode_v1(),
            MavlinkVersion::V2 => self.encode_v2(),
        }
    }

    fn encode_v1(&self) -> Vec<u8> {
        let payload = &self.payload[..self.payload.len().min(255)];
        let id = (self.msg_id & 0xff) as u8;
        let mut b = Vec::with_capacity(8 + payload.len());
        b.extend_from_slice(&[
            0xfe,
            payload.len() as u8,
            self.seq,
            (self.sys & 0xff) as u8,
            self.comp,
            id,
        ]);
        b.extend_from_slice(payload);
        let crc = mavlink::calculate_crc(&b[1..], apm::MavMessage::extra_crc(u32::from(id)));
        b.extend_from_slice(&(crc ^ self.crc_xor).to_le_bytes());
        b
    }

    fn encode_v2(&self) -> Vec<u8> {
        let mut payload = &self.payload[..self.payload.len().min(255)];
        // MAVLink 2 senders drop trailing zero bytes (at least one byte stays).
        while payload.len() > 1 && payload.last() == Some(&0) {
            payload = &payload[..payload.len() - 1];
        }
        let sys32 = self.sys > 0xff;
        let mut iflags = self.extra_iflags;
        if sys32 {
            iflags |= IFLAG_SYSID32;
        }
        if self.signature.is_some() {
            iflags |= IFLAG_SIGNED;
        }
        let id = self.msg_id & 0x00ff_ffff;
        let mut b = Vec::with_capacity(30 + payload.len());
        b.extend_from_slice(&[0xfd, payload.len() as u8, iflags, self.compat, self.seq]);
        if iflags & IFLAG_SYSID32 != 0 {
            b.extend_from_slice(&self.sys.to_le_bytes());
        } else {
            b.push((self.sys & 0xff) as u8);
        }
        b.push(self.comp);
        b.extend_from_slice(&id.to_le_bytes()[..3]);
        b.extend_from_slice(payload);
        let crc = mavlink::calculate_crc(&b[1..], apm::MavMessage::extra_crc(id));
        b.extend_from_slice(&(crc ^ self.crc_xor).to_le_bytes());
        if iflags & IFLAG_SIGNED != 0 {
            let sig = self.signature.unwrap_or(Signature {
                link_id: 0,
                timestamp: 0,
                key: [0; 32],
            });
            let unsigned_len = b.len();
            b.push(sig.link_id);
            b.extend_from_slice(&sig.timestamp.to_le_bytes()[..6]);
            b.extend_from_slice(&[0; 6]);
            let mut raw = [0_u8; mavlink::consts::MAX_FRAME_SIZE];
            if b.len() <= raw.len() {
                raw[..b.len()].copy_from_slice(&b);
                let raw = MAVLinkV2MessageRaw::from_bytes_unparsed(raw);
                let mut value = [0_u8; 6];
                raw.calculate_signature(&sig.key, &mut value);
                b[unsigned_len + 7..].copy_from_slice(&value);
            }
        }
        b
    }
}

/// Bytes of a message frame as an honest sender (our simulated autopilot) writes it.
pub fn frame(
    msg: &apm::MavMessage,
    version: MavlinkVersion,
    sys: u32,
    comp: u8,
    seq: u8,
) -> Vec<u8> {
    FrameSpec::of(msg, version, sys, comp, seq).encode()
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::{MavlinkReader, SigningConfig, SigningData};

    fn heartbeat() -> apm::MavMessage {
        apm::MavMessage::HEARTBEAT(apm::HEARTBEAT_DATA {
            autopilot: apm::MavAutopilot::MAV_AUTOPILOT_PX4,
            mavtype: apm::MavType::MAV_TYPE_FIXED_WING,
            ..Default::default()
        })
    }

    #[test]
    fn hand_written_frames_are_read_back_by_the_mavlink_crate() {
        let mut bytes = frame(&heartbeat(), MavlinkVersion::V1, 1, 1, 7);
        bytes.extend(frame(&heartbeat(), MavlinkVersion::V2, 300, 1, 8));
        let mut spec = FrameSpec::of(&heartbeat(), MavlinkVersion::V2, 1, 1, 9);
        spec.signature = Some(Signature {
            link_id: 3,
            timestamp: SIGNATURE_TS_BASE,
            key: SIGNING_KEY,
        });
        bytes.extend(spec.encode());
        let signing = SigningData::from_config(SigningConfig::new(SIGNING_KEY, 0, true, true));
        let mut r = MavlinkReader::new(bytes.as_slice());
        let mut got = Vec::new();
        while let Ok(raw) = r.read_any_raw_message_signed::<apm::MavMessage>(Some(&signing)) {
            got.push((raw.version(), raw.system_id(), raw.sequence()));
        }
        assert_eq!(
            got,
            vec![
                (MavlinkVersion::V1, 1, 7),
                (MavlinkVersion::V2, 300, 8),
                (MavlinkVersion::V2, 1, 9)
            ]
        );
        // A bad CRC or a wrong key: dropped by the crate.
        spec.crc_xor = 1;
        let bad_crc = spec.encode();
        spec.crc_xor = 0;
        spec.signature = spec.signature.map(|s| Signature {
            key: [1; 32],
            timestamp: s.timestamp + 1,
            ..s
        });
        let bad_key = spec.encode();
        for bytes in [bad_crc, bad_key] {
            let mut r = MavlinkReader::new(bytes.as_slice());
            assert!(
                r.read_any_raw_message_signed::<apm::MavMessage>(Some(&signing))
                    .is_err()
            );
        }
    }
}
