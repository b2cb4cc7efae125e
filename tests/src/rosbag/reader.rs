//! Streams the messages of a rosbag2 bag stored as MCAP: a bag folder
//! (`metadata.yaml` and its `.mcap` files, read in name order) or one `.mcap`
//! file. The `mcap` crate's sans-IO linear reader pulls the file in blocks and
//! decompresses one chunk at a time, so memory stays bounded by the largest
//! chunk whatever the bag's size.

use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};

use mcap::records::Record;
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader};

use crate::error::SimError;

/// A channel of the bag: its topic and its message type with its definition.
#[derive(Clone, Debug, PartialEq)]
pub struct Topic {
    /// Topic name, e.g. `/r1/audio/audio_stamped`.
    pub name: String,
    /// Message type, e.g. `audio_common_msgs/msg/AudioDataStamped`.
    pub msg_type: String,
    /// The message definition (`ros2msg` text), empty when the writer gave none.
    pub definition: String,
    /// Message encoding, `cdr` for ROS 2.
    pub encoding: String,
}

/// The `.mcap` files of a bag: `bag` itself when it is a file, else those of the folder.
pub fn bag_files(bag: &Path) -> Result<Vec<PathBuf>, SimError> {
    if bag.is_file() {
        return Ok(vec![bag.to_path_buf()]);
    }
    let entries = std::fs::read_dir(bag).map_err(|e| SimError::file(bag, e))?;
    let mut files: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
    files.sort();
    let sqlite = files.iter().any(|f| f.extension().is_some_and(|e| e == "db3"));
    files.retain(|f| f.extension().is_some_and(|e| e == "mcap"));
    if files.is_empty() {
        let why = if sqlite {
            "it holds SQLite (.db3) storage: convert it with `ros2 bag convert` to MCAP".to_string()
        } else {
            "no .mcap file in it".to_string()
        };
        return Err(SimError::Replay(format!("{}: not a rosbag2 MCAP bag: {why}", bag.display())));
    }
    Ok(files)
}

/// One message: its topic and its CDR bytes.
pub type Message = (std::rc::Rc<Topic>, Vec<u8>);

/// Messages of a bag in file order.
///
/// A bag file cut short (the recorder killed or the robot's power lost
/// before it closed the file) ends in the middle of a record: its messages
/// up to the last complete record (for a chunked file, the last complete
/// chunk) are read and the file is listed in [`BagMessages::cut_short`],
/// instead of the whole bag being refused.
pub struct BagMessages {
    files: Vec<PathBuf>,
    current: Option<(PathBuf, std::fs::File, LinearReader)>,
    schemas: HashMap<u16, (String, String)>,
    channels: HashMap<u16, std::rc::Rc<Topic>>,
    cut_short: Vec<PathBuf>,
}

impl std::fmt::Debug for BagMessages {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BagMessages").field("files", &self.files).finish_non_exhaustive()
    }
}

impl BagMessages {
    /// Opens the bag's files (read lazily).
    pub fn open(bag: &Path) -> Result<Self, SimError> {
        let mut files = bag_files(bag)?;
        files.reverse();
        Ok(BagMessages {
            files,
            current: None,
            schemas: HashMap::new(),
            channels: HashMap::new(),
            cut_short: Vec::new(),
        })
    }

    /// The files read so far that end in the middle of a record.
    pub fn cut_short(&self) -> &[PathBuf] {
        &self.cut_short
    }

    /// The next message.
    pub fn next_message(&mut self) -> Result<Option<Message>, SimError> {
        loop {
            if self.current.is_none() {
                let Some(path) = self.files.pop() else { return Ok(None) };
                let file = std::fs::File::open(&path).map_err(|e| SimError::file(&path, e))?;
                // A new file numbers its schemas and channels anew.
                self.schemas.clear();
                self.channels.clear();
                self.current = Some((path, file, LinearReader::new()));
            }
            let (path, file, reader) = self.current.as_mut().expect("a file is open");
            let bad = |e: mcap::McapError| {
                SimError::Replay(format!("{}: not a readable MCAP file: {e}", path.display()))
            };
            let Some(event) = reader.next_event() else {
                self.current = None;
                continue;
            };
            if let Err(mcap::McapError::UnexpectedEof) = event {
                let (path, ..) = self.current.take().expect("a file is open");
                self.cut_short.push(path);
                continue;
            }
            match event.map_err(bad)? {
                LinearReadEvent::ReadRequest(n) => {
                    let read = file.read(reader.insert(n)).map_err(|e| SimError::file(path.clone(), e))?;
                    reader.notify_read(read);
                }
                LinearReadEvent::Record { data, opcode } => {
                    match mcap::parse_record(opcode, data).map_err(bad)? {
                        Record::Schema { header, data } => {
                            let text = String::from_utf8_lossy(&data).into_owned();
                            self.schemas.insert(header.id, (header.name, text));
                        }
                        Record::Channel(c) => {
                            let (msg_type, definition) =
                                self.schemas.get(&c.schema_id).cloned().unwrap_or_default();
                            let topic =
                                Topic { name: c.topic, msg_type, definition, encoding: c.message_encoding };
                            self.channels.insert(c.id, std::rc::Rc::new(topic));
                        }
                        Record::Message { header, data } => {
                            let Some(topic) = self.channels.get(&header.channel_id) else {
                                return Err(SimError::Replay(format!(
                                    "{}: a message on channel {} that was never declared",
                                    path.display(),
                                    header.channel_id
                                )));
                            };
                            return Ok(Some((topic.clone(), data.into_owned())));
                        }
                        _ => {}
                    }
                }
            }
        }
    }
}
