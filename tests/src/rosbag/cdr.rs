//! The ROS 2 messages soundmap reads from bags, decoded from CDR, and the
//! check that a channel's message definition is the one they are decoded as.
//!
//! CDR (XCDR1, as rosbag2 writes it): a 4-byte encapsulation header
//! (`00 01` little endian, `00 00` big endian, then 2 option bytes), then the
//! fields in definition order, each primitive aligned to its own size counted
//! from the end of the header; a string is a `uint32` length (with its NUL)
//! and the bytes; a sequence is a `uint32` count and the elements. Nested
//! messages add no padding of their own. For example a `TFMessage` holding
//! one transform: count (4 B) · header.stamp.sec, .nanosec (8 B) ·
//! frame_id "map\0" (4 + 4 B) · child_frame_id · 4 B padding to 8 ·
//! translation x, y, z and rotation x, y, z, w (7 × 8 B).

/// A CDR reader over one message.
#[derive(Debug)]
pub struct Cdr<'a> {
    body: &'a [u8],
    pos: usize,
    little: bool,
}

impl<'a> Cdr<'a> {
    /// Reads the encapsulation header.
    pub fn new(data: &'a [u8]) -> Result<Self, String> {
        if data.len() < 4 {
            return Err(format!("{} bytes: shorter than the CDR header", data.len()));
        }
        let little = match (data[0], data[1]) {
            (0, 1) => true,
            (0, 0) => false,
            (a, b) => return Err(format!("encapsulation {a:#04x}{b:02x} is not plain CDR")),
        };
        Ok(Cdr { body: &data[4..], pos: 0, little })
    }

    fn take(&mut self, n: usize, align: usize) -> Result<&'a [u8], String> {
        self.pos = self.pos.div_ceil(align) * align;
        let end = self.pos.checked_add(n).filter(|e| *e <= self.body.len()).ok_or_else(|| {
            format!("truncated: {n} bytes wanted at offset {}, {} in the message", self.pos, self.body.len())
        })?;
        let bytes = &self.body[self.pos..end];
        self.pos = end;
        Ok(bytes)
    }

    fn array<const N: usize>(&mut self) -> Result<[u8; N], String> {
        let mut a: [u8; N] = self.take(N, N)?.try_into().expect("N bytes");
        if !self.little {
            a.reverse();
        }
        Ok(a)
    }

    /// `uint8`.
    pub fn u8(&mut self) -> Result<u8, String> {
        Ok(self.take(1, 1)?[0])
    }
    /// `uint32`.
    pub fn u32(&mut self) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.array()?))
    }
    /// `int32`.
    pub fn i32(&mut self) -> Result<i32, String> {
        Ok(i32::from_le_bytes(self.array()?))
    }
    /// `float64`.
    pub fn f64(&mut self) -> Result<f64, String> {
        Ok(f64::from_le_bytes(self.array()?))
    }
    /// `string`.
    pub fn string(&mut self) -> Result<String, String> {
        let n = self.u32()? as usize;
        let bytes = self.take(n, 1)?;
        let text = bytes.strip_suffix(&[0]).unwrap_or(bytes);
        String::from_utf8(text.to_vec()).map_err(|_| "a string is not UTF-8".to_string())
    }
    /// `uint8[]`.
    pub fn bytes(&mut self) -> Result<&'a [u8], String> {
        let n = self.u32()? as usize;
        self.take(n, 1)
    }
    /// A sequence count.
    pub fn count(&mut self) -> Result<usize, String> {
        Ok(self.u32()? as usize)
    }
}

/// `std_msgs/Header`: the stamp in Unix ns and the frame.
fn header(c: &mut Cdr<'_>) -> Result<(i64, String), String> {
    let sec = c.i32()? as i64;
    let nanosec = c.u32()? as i64;
    Ok((sec * 1_000_000_000 + nanosec, c.string()?))
}

/// `audio_common_msgs/msg/AudioInfo`.
#[derive(Clone, Debug, PartialEq)]
pub struct AudioInfo {
    /// Channels per frame.
    pub channels: u8,
    /// Sample rate, Hz.
    pub sample_rate: u32,
    /// Sample format, e.g. `S16LE`.
    pub sample_format: String,
    /// Bits per second (unused).
    pub bitrate: u32,
    /// Coding format, e.g. `wave`.
    pub coding_format: String,
}

impl AudioInfo {
    /// Decodes one message.
    pub fn decode(data: &[u8]) -> Result<Self, String> {
        let mut c = Cdr::new(data)?;
        Ok(AudioInfo {
            channels: c.u8()?,
            sample_rate: c.u32()?,
            sample_format: c.string()?,
            bitrate: c.u32()?,
            coding_format: c.string()?,
        })
    }
}

/// `audio_common_msgs/msg/AudioDataStamped`: the stamp of the first sample (Unix ns) and the bytes.
pub fn audio_data_stamped(data: &[u8]) -> Result<(i64, &[u8]), String> {
    let mut c = Cdr::new(data)?;
    let (stamp, _) = header(&mut c)?;
    Ok((stamp, c.bytes()?))
}

/// One `geometry_msgs/TransformStamped`: `parent_from_child` at `stamp_ns`.
#[derive(Clone, Debug, PartialEq)]
pub struct Transform {
    /// Stamp, Unix ns.
    pub stamp_ns: i64,
    /// `header.frame_id`.
    pub parent: String,
    /// `child_frame_id`.
    pub child: String,
    /// Translation, m.
    pub translation: [f64; 3],
    /// Rotation quaternion x, y, z, w.
    pub rotation: [f64; 4],
}

/// `tf2_msgs/msg/TFMessage`.
pub fn tf_message(data: &[u8]) -> Result<Vec<Transform>, String> {
    let mut c = Cdr::new(data)?;
    let n = c.count()?;
    let mut out = Vec::with_capacity(n.min(1024));
    for _ in 0..n {
        let (stamp_ns, parent) = header(&mut c)?;
        let child = c.string()?;
        let translation = [c.f64()?, c.f64()?, c.f64()?];
        let rotation = [c.f64()?, c.f64()?, c.f64()?, c.f64()?];
        out.push(Transform { stamp_ns, parent, child, translation, rotation });
    }
    Ok(out)
}

/// The message types soundmap reads, with the fields (type, name) their CDR
/// decoding above assumes, top-level type first, then the nested ones.
pub const AUDIO_DATA_STAMPED: &[(&str, &[(&str, &str)])] = &[
    ("audio_common_msgs/AudioDataStamped", &[("Header", "header"), ("AudioData", "audio")]),
    ("audio_common_msgs/AudioData", &[("uint8[]", "data")]),
    ("std_msgs/Header", &[("Time", "stamp"), ("string", "frame_id")]),
];
/// See [`AUDIO_DATA_STAMPED`].
pub const AUDIO_INFO: &[(&str, &[(&str, &str)])] = &[(
    "audio_common_msgs/AudioInfo",
    &[
        ("uint8", "channels"),
        ("uint32", "sample_rate"),
        ("string", "sample_format"),
        ("uint32", "bitrate"),
        ("string", "coding_format"),
    ],
)];
/// See [`AUDIO_DATA_STAMPED`].
pub const TF_MESSAGE: &[(&str, &[(&str, &str)])] = &[
    ("tf2_msgs/TFMessage", &[("TransformStamped[]", "transforms")]),
    (
        "geometry_msgs/TransformStamped",
        &[("Header", "header"), ("string", "child_frame_id"), ("Transform", "transform")],
    ),
    ("geometry_msgs/Transform", &[("Vector3", "translation"), ("Quaternion", "rotation")]),
    ("geometry_msgs/Vector3", &[("float64", "x"), ("float64", "y"), ("float64", "z")]),
    ("geometry_msgs/Quaternion", &[("float64", "x"), ("float64", "y"), ("float64", "z"), ("float64", "w")]),
    ("std_msgs/Header", &[("Time", "stamp"), ("string", "frame_id")]),
];

/// `pkg/msg/Name` → `pkg/Name`.
fn short(name: &str) -> String {
    name.replace("/msg/", "/")
}

/// The fields (type without package, name) of each message of a `ros2msg`
/// definition: the top-level one under `top`, nested ones under their `MSG:` name.
fn sections(top: &str, text: &str) -> Vec<(String, Vec<(String, String)>)> {
    let mut out = vec![(short(top), Vec::new())];
    for line in text.lines() {
        let line = line.split('#').next().unwrap_or("").trim();
        if line.starts_with("====") || line.is_empty() {
            continue;
        }
        if let Some(name) = line.strip_prefix("MSG:") {
            out.push((short(name.trim()), Vec::new()));
            continue;
        }
        let mut words = line.split_whitespace();
        let (Some(ty), Some(name)) = (words.next(), words.next()) else { continue };
        if name.contains('=') || words.next().is_some_and(|w| w.starts_with('=')) {
            continue; // a constant
        }
        let ty = ty.rsplit('/').next().unwrap_or(ty).to_string();
        out.last_mut().expect("one section").1.push((ty, name.to_string()));
    }
    out
}

/// Checks that the definition `text` of type `name` (a channel's schema)
/// declares the fields `expected` describes, for every message it defines.
pub fn check_definition(name: &str, text: &str, expected: &[(&str, &[(&str, &str)])]) -> Result<(), String> {
    if short(name) != expected[0].0 {
        return Err(format!("has type {name}, expected {}", expected[0].0.replace('/', "/msg/")));
    }
    let found = sections(name, text);
    for (ty, fields) in expected {
        let Some((_, have)) = found.iter().find(|(n, _)| n == ty) else {
            if *ty == expected[0].0 {
                return Err(format!("{name}: the bag holds no definition of it"));
            }
            continue; // nested definitions may be left out by the writer
        };
        let want: Vec<(String, String)> =
            fields.iter().map(|(t, n)| (t.to_string(), n.to_string())).collect();
        if *have != want {
            let show = |f: &[(String, String)]| {
                f.iter().map(|(t, n)| format!("{t} {n}")).collect::<Vec<_>>().join("; ")
            };
            return Err(format!(
                "unknown message definition of {ty}: fields [{}], soundmap reads [{}]",
                show(have),
                show(&want)
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tf_message_decodes_with_alignment() {
        let mut b = vec![0u8, 1, 0, 0];
        let push = |b: &mut Vec<u8>, bytes: &[u8]| b.extend_from_slice(bytes);
        push(&mut b, &1u32.to_le_bytes());
        push(&mut b, &7i32.to_le_bytes());
        push(&mut b, &5u32.to_le_bytes());
        push(&mut b, &4u32.to_le_bytes());
        push(&mut b, b"map\0");
        push(&mut b, &5u32.to_le_bytes());
        push(&mut b, b"odom\0");
        while (b.len() - 4) % 8 != 0 {
            b.push(0);
        }
        for v in [1.0f64, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0] {
            push(&mut b, &v.to_le_bytes());
        }
        let t = tf_message(&b).unwrap();
        assert_eq!(t.len(), 1);
        assert_eq!(
            (t[0].stamp_ns, t[0].parent.as_str(), t[0].child.as_str()),
            (7_000_000_005, "map", "odom")
        );
        assert_eq!((t[0].translation, t[0].rotation), ([1.0, 2.0, 3.0], [0.0, 0.0, 0.0, 1.0]));
        assert!(tf_message(&b[..b.len() - 1]).unwrap_err().contains("truncated"));
    }

    #[test]
    fn definitions_are_checked_field_by_field() {
        let good = "uint8 channels\nuint32 sample_rate\nstring sample_format\nuint32 bitrate\nstring coding_format\n";
        check_definition("audio_common_msgs/msg/AudioInfo", good, AUDIO_INFO).unwrap();
        let other = "uint8 channels\nuint32 rate\n";
        let e = check_definition("audio_common_msgs/msg/AudioInfo", other, AUDIO_INFO).unwrap_err();
        assert!(e.contains("unknown message definition") && e.contains("uint32 rate"), "{e}");
        let e = check_definition("sensor_msgs/msg/Imu", good, AUDIO_INFO).unwrap_err();
        assert!(e.contains("expected audio_common_msgs/msg/AudioInfo"), "{e}");
        let stamped = "std_msgs/Header header\naudio_common_msgs/AudioData audio\n\
            ================================================================================\n\
            MSG: audio_common_msgs/AudioData\nuint8[] data\n\
            ================================================================================\n\
            MSG: std_msgs/Header\n# comment\nbuiltin_interfaces/Time stamp\nstring frame_id\n";
        check_definition("audio_common_msgs/msg/AudioDataStamped", stamped, AUDIO_DATA_STAMPED).unwrap();
    }
}
