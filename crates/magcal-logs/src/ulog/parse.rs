//! The records of a ULog read into [`super::Raw`] within a memory budget: the header, the
//! definitions (formats, parameters, subscriptions), and the data of the topics the reader keeps,
//! each record checked where it stands.

use super::*;

/// The running charge of what is kept against half of the memory the process may use.
pub(super) struct Budget {
    pub(super) used: u64,
    pub(super) limit: Option<(u64, u64, &'static str)>,
}

impl Budget {
    pub(super) fn new() -> Self {
        Self {
            used: 0,
            limit: limits::available_memory().map(|(a, what)| (a / 2, a, what)),
        }
    }

    fn charge(&mut self, bytes: u64, shown: &str, offset: u64) -> Result<()> {
        self.used = self.used.saturating_add(bytes);
        if let Some((limit, available, what)) = self.limit
            && self.used > limit
        {
            bail!(
                "{shown}: byte {offset}: the log holds more than fits in memory (the readings, series and parameters kept so far take {}; the limit is {}, half of {} {what})",
                limits::bytes(self.used),
                limits::bytes(limit),
                limits::bytes(available)
            );
        }
        Ok(())
    }
}

/// The file as a stream of bytes with its position.
struct Stream<'a, R> {
    inner: &'a mut R,
    pos: u64,
    shown: &'a str,
}

impl<R: Read> Stream<'_, R> {
    /// Reads into `buf` until it is full or the file ends; returns the bytes read.
    fn fill(&mut self, buf: &mut [u8]) -> Result<usize> {
        let mut got = 0;
        while got < buf.len() {
            match self.inner.read(&mut buf[got..]) {
                Ok(0) => break,
                Ok(n) => got += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => {
                    return Err(e).with_context(|| {
                        format!("{}: cannot read the log at byte {}", self.shown, self.pos + got as u64)
                    });
                }
            }
        }
        self.pos += got as u64;
        Ok(got)
    }

    /// Skips `n` bytes; the file must hold them.
    fn skip(&mut self, n: u64, why: &str) -> Result<()> {
        let start = self.pos;
        let mut left = n;
        let mut buf = [0u8; 4096];
        while left > 0 {
            let want = left.min(buf.len() as u64) as usize;
            let got = self.fill(&mut buf[..want])?;
            if got == 0 {
                bail!(
                    "{}: byte {start}: {why} at byte {}, past the end of the file (byte {}): truncated or corrupt",
                    self.shown,
                    start + n,
                    self.pos
                );
            }
            left -= got as u64;
        }
        Ok(())
    }
}

/// Reads the whole file once, keeping what [`assemble`] needs: the header, then one message at a
/// time, each handed to [`Pass::take`].
pub(super) fn parse<R: Read>(reader: &mut R, shown: &str, budget: Budget) -> Result<Raw> {
    let mut s = Stream {
        inner: reader,
        pos: 0,
        shown,
    };
    let mut pass = Pass::new(file_version(&mut s)?, budget);
    let mut first = true;
    let mut payload = vec![0u8; usize::from(u16::MAX)];
    loop {
        let at = s.pos;
        // The appended data starts here, or within the next message header's bytes.
        if pass.skip_to_appended(&mut s, at, at + 3)? {
            continue;
        }
        let mut head = [0u8; 3];
        let got = s.fill(&mut head)?;
        if got == 0 {
            break;
        }
        if got < 3 {
            bail!("{shown}: byte {at}: the file ends inside a message header ({got} of 3 bytes): truncated");
        }
        let size = usize::from(u16::from_le_bytes([head[0], head[1]]));
        let kind = head[2];
        let end = at + 3 + size as u64;
        // Appended data (a crash log's tail) starts at a fixed offset: a message of the main
        // section that runs past it was cut where the appended data was written.
        if pass.skip_to_appended(&mut s, at, end)? {
            continue;
        }
        let got = s.fill(&mut payload[..size])?;
        if got < size {
            bail!(
                "{shown}: byte {at}: message '{}' of {size} bytes ends at byte {end}, past the end of the file (byte {}): truncated",
                show_type(kind),
                s.pos
            );
        }
        let msg = Message {
            shown,
            at,
            kind,
            body: &payload[..size],
        };
        pass.take(&msg, first)?;
        first = false;
    }
    if let Some(&next) = pass.appended.first()
        && next > s.pos
    {
        bail!(
            "{shown}: the flag bits announce appended data at byte {next}, past the end of the file (byte {}): truncated",
            s.pos
        );
    }
    Ok(pass.raw)
}

/// Reads the 16-byte header: the ULog magic, then the file version, returned.
fn file_version<R: Read>(s: &mut Stream<'_, R>) -> Result<u8> {
    let mut header = [0u8; 16];
    let got = s.fill(&mut header)?;
    if got < 16 || header[..7] != MAGIC {
        bail!(
            "{}: not a PX4 ULog file (it does not start with the 16-byte ULog header \"ULog\" 01 12 35)",
            s.shown
        );
    }
    Ok(header[7])
}

/// One message as read: where it starts, its type and its payload (after the 3-byte header).
struct Message<'a> {
    shown: &'a str,
    at: u64,
    kind: u8,
    body: &'a [u8],
}

impl Message<'_> {
    /// The byte after the message.
    fn end(&self) -> u64 {
        self.at + 3 + self.body.len() as u64
    }

    /// The text of an error about this message: the file, its byte offset, type and size, `what`.
    fn error(&self, what: &str) -> String {
        format!(
            "{}: byte {}: message '{}' ({} bytes): {what}",
            self.shown,
            self.at,
            show_type(self.kind),
            self.body.len()
        )
    }
}

/// What the pass over the file holds while it reads: what it keeps, and the state of the log
/// (formats, subscriptions, whether the data section began, appended data still ahead).
struct Pass {
    raw: Raw,
    budget: Budget,
    formats: HashMap<String, Vec<FieldDef>>,
    /// Bytes of the formats sized so far.
    sizes: HashMap<String, u64>,
    /// The decoder of each message id added, `None` for a topic not read.
    subs: HashMap<u16, Option<Decoder>>,
    in_data: bool,
    /// Byte offsets where appended data starts, ascending, those not reached yet.
    appended: Vec<u64>,
}

impl Pass {
    fn new(version: u8, budget: Budget) -> Self {
        Self {
            raw: Raw {
                version,
                ..Raw::default()
            },
            budget,
            formats: HashMap::new(),
            sizes: HashMap::new(),
            subs: HashMap::new(),
            in_data: false,
            appended: Vec::new(),
        }
    }

    /// Skips from `at` to the next appended data when it starts before `upto`, counting the
    /// bytes skipped since `at`; whether it did.
    fn skip_to_appended<R: Read>(&mut self, s: &mut Stream<'_, R>, at: u64, upto: u64) -> Result<bool> {
        let Some(&next) = self.appended.first() else {
            return Ok(false);
        };
        if next >= upto {
            return Ok(false);
        }
        self.raw.skipped_before_appended += next.saturating_sub(at);
        s.skip(next.saturating_sub(s.pos), "the appended data starts")?;
        self.appended.remove(0);
        Ok(true)
    }

    /// Takes one message; `first` when it is the first after the header.
    fn take(&mut self, msg: &Message<'_>, first: bool) -> Result<()> {
        match msg.kind {
            b'B' => self.flag_bits(msg, first),
            b'F' => self.format(msg),
            b'I' | b'M' => self.info(msg),
            b'P' | b'Q' => self.parameter(msg),
            b'A' => self.add_logged(msg),
            b'R' => self.remove_logged(msg),
            b'D' => self.data(msg),
            b'O' => self.dropout(msg),
            b'L' | b'C' | b'S' => {
                self.in_data = true;
                Ok(())
            }
            other if other.is_ascii_alphabetic() => {
                *self.raw.unknown.entry(other).or_default() += 1;
                Ok(())
            }
            _ => bail!("{}", msg.error("not a ULog message type: corrupt")),
        }
    }

    /// `B`, the flag bits: incompatible flags this reader does not know are an error; the
    /// offsets of appended data are kept.
    fn flag_bits(&mut self, msg: &Message<'_>, first: bool) -> Result<()> {
        let body = msg.body;
        if !first {
            bail!("{}", msg.error("flag bits are allowed only as the first message"));
        }
        if body.len() < 40 {
            bail!("{}", msg.error("flag bits need 40 bytes"));
        }
        let incompat = &body[8..16];
        if incompat[0] & !1 != 0 || incompat[1..].iter().any(|&b| b != 0) {
            bail!(
                "{}",
                msg.error(&format!(
                    "incompatible flags {incompat:02x?} that this reader does not know: a newer ULog"
                ))
            );
        }
        if incompat[0] & 1 != 0 {
            for k in 0..3 {
                let o = u64::from_le_bytes(body[16 + 8 * k..24 + 8 * k].try_into().expect("8 bytes"));
                if o != 0 {
                    if o < msg.end() || self.appended.last().is_some_and(|&p| o <= p) {
                        bail!(
                            "{}",
                            msg.error(&format!(
                                "appended data offset {o} is not after the flag bits and ascending"
                            ))
                        );
                    }
                    self.appended.push(o);
                }
            }
        }
        Ok(())
    }

    /// `F`, a format: kept by name, each name once.
    fn format(&mut self, msg: &Message<'_>) -> Result<()> {
        let text = std::str::from_utf8(msg.body)
            .map_err(|_| anyhow::anyhow!("{}", msg.error("a format that is not UTF-8")))?;
        let (fname, fields) = parse_format(text).map_err(|e| anyhow::anyhow!("{}", msg.error(&e)))?;
        if self.formats.len() >= MAX_FORMATS {
            bail!(
                "{}",
                msg.error(&format!(
                    "more than {MAX_FORMATS} formats (a PX4 log defines a few hundred): not a log to read"
                ))
            );
        }
        let held = msg.body.len() as u64 + HELD_PER_ENTRY * (1 + fields.len() as u64);
        self.budget.charge(held, msg.shown, msg.at)?;
        if self.formats.insert(fname.clone(), fields).is_some() {
            bail!("{}", msg.error(&format!("format {} defined twice", excerpt(&fname))));
        }
        Ok(())
    }

    /// `I` or `M`, an information message (`M` with its multi-message flag): the `uint32_t`
    /// values, and the texts `ver_sw`, `ver_hw`, `sys_name`, `ver_sw_branch`, are kept.
    fn info(&mut self, msg: &Message<'_>) -> Result<()> {
        let (body, size) = (msg.body, msg.body.len());
        let skip = usize::from(msg.kind == b'M');
        if size < 1 + skip {
            bail!("{}", msg.error("too short"));
        }
        let key_len = usize::from(body[skip]);
        if 1 + skip + key_len > size {
            bail!(
                "{}",
                msg.error(&format!("a key of {key_len} bytes runs past the message"))
            );
        }
        let key = std::str::from_utf8(&body[1 + skip..1 + skip + key_len])
            .map_err(|_| anyhow::anyhow!("{}", msg.error("a key that is not UTF-8")))?;
        let value = &body[1 + skip + key_len..];
        if msg.kind == b'I'
            && let Some((ty, k)) = key.split_once(' ')
        {
            if ty == "uint32_t" && value.len() == 4 {
                self.budget.charge(HELD_PER_ENTRY + k.len() as u64, msg.shown, msg.at)?;
                self.raw
                    .info_u32
                    .insert(k.to_string(), u32::from_le_bytes(value.try_into().expect("4 bytes")));
            } else if ty.starts_with("char[") && matches!(k, "ver_sw" | "ver_hw" | "sys_name" | "ver_sw_branch") {
                let text = String::from_utf8_lossy(value).trim_end_matches('\0').to_string();
                self.raw.info_text.insert(k.to_string(), text);
            }
        }
        Ok(())
    }

    /// `P`, a parameter, or `Q`, a parameter default (checked, not kept): a `float` or
    /// `int32_t`, kept as in force at the start where it comes before the data section, else
    /// as a change at its byte offset.
    fn parameter(&mut self, msg: &Message<'_>) -> Result<()> {
        let (body, size) = (msg.body, msg.body.len());
        let skip = usize::from(msg.kind == b'Q');
        if size < 1 + skip {
            bail!("{}", msg.error("too short"));
        }
        let key_len = usize::from(body[skip]);
        if 1 + skip + key_len + 4 != size {
            bail!(
                "{}",
                msg.error(&format!(
                    "a key of {key_len} bytes and a 4-byte value do not make {size} bytes"
                ))
            );
        }
        let key = std::str::from_utf8(&body[1 + skip..1 + skip + key_len])
            .map_err(|_| anyhow::anyhow!("{}", msg.error("a parameter name that is not UTF-8")))?;
        let bytes: [u8; 4] = body[size - 4..].try_into().expect("4 bytes");
        let (ty, pname) = key
            .split_once(' ')
            .ok_or_else(|| anyhow::anyhow!("{}", msg.error(&format!("parameter {} has no type", excerpt(key)))))?;
        let value = match ty {
            "float" => Param::Float(f32::from_le_bytes(bytes)),
            "int32_t" => Param::Int(i32::from_le_bytes(bytes)),
            _ => bail!(
                "{}",
                msg.error(&format!(
                    "parameter {} of type {}, which ULog does not have (float and int32_t): a damaged log",
                    excerpt(pname),
                    excerpt(ty)
                ))
            ),
        };
        if msg.kind == b'P' {
            self.budget.charge(HELD_PER_ENTRY + key_len as u64, msg.shown, msg.at)?;
            if self.in_data {
                self.raw.changes.push((msg.at, pname.to_string(), value));
            } else {
                self.raw.initial.insert(pname.to_string(), value);
            }
        }
        Ok(())
    }

    /// `A`, a subscription added: its message id, with the decoder of a topic this reader reads.
    fn add_logged(&mut self, msg: &Message<'_>) -> Result<()> {
        let body = msg.body;
        self.in_data = true;
        if body.len() < 4 {
            bail!("{}", msg.error("too short for an add-logged message"));
        }
        let multi_id = body[0];
        let id = u16::from_le_bytes([body[1], body[2]]);
        let topic = std::str::from_utf8(&body[3..])
            .map_err(|_| anyhow::anyhow!("{}", msg.error("a topic name that is not UTF-8")))?;
        if !self.formats.contains_key(topic) {
            bail!("{}", msg.error(&format!("topic {} has no format", excerpt(topic))));
        }
        let decoder = match Topic::from_name(topic) {
            Some(t) => Some(
                decoder(t, multi_id, &self.formats, &mut self.sizes)
                    .map_err(|e| anyhow::anyhow!("{}", msg.error(&e)))?,
            ),
            None => None,
        };
        self.budget.charge(HELD_PER_ENTRY, msg.shown, msg.at)?;
        if self.subs.insert(id, decoder).is_some() {
            bail!("{}", msg.error(&format!("message id {id} added twice")));
        }
        Ok(())
    }

    /// `R`, a subscription removed.
    fn remove_logged(&mut self, msg: &Message<'_>) -> Result<()> {
        self.in_data = true;
        if msg.body.len() < 2 {
            bail!("{}", msg.error("too short"));
        }
        self.subs.remove(&u16::from_le_bytes([msg.body[0], msg.body[1]]));
        Ok(())
    }

    /// `D`, data of a subscription: decoded and kept where its topic is read.
    fn data(&mut self, msg: &Message<'_>) -> Result<()> {
        let body = msg.body;
        if body.len() < 2 {
            bail!("{}", msg.error("too short for a data message"));
        }
        let id = u16::from_le_bytes([body[0], body[1]]);
        let Some(sub) = self.subs.get(&id) else {
            bail!(
                "{}",
                msg.error(&format!(
                    "data of message id {id}, which no add-logged message announced"
                ))
            );
        };
        if let Some(d) = sub {
            let data = &body[2..];
            if data.len() < d.need {
                bail!(
                    "{}",
                    msg.error(&format!(
                        "{} (multi_id {}) needs {} bytes of data, the message has {}",
                        d.topic.name(),
                        d.multi_id,
                        d.need,
                        data.len()
                    ))
                );
            }
            keep(&mut self.raw, d, data, msg.at, &mut self.budget, msg.shown)?;
        }
        Ok(())
    }

    /// `O`, a dropout: counted, with its milliseconds.
    fn dropout(&mut self, msg: &Message<'_>) -> Result<()> {
        self.in_data = true;
        if msg.body.len() < 2 {
            bail!("{}", msg.error("too short"));
        }
        self.raw.dropouts += 1;
        self.raw.dropout_ms += u64::from(u16::from_le_bytes([msg.body[0], msg.body[1]]));
        Ok(())
    }
}

/// A message type for an error: its letter, or its code.
fn show_type(t: u8) -> String {
    if t.is_ascii_graphic() {
        char::from(t).to_string()
    } else {
        format!("0x{t:02x}")
    }
}

/// At most [`crate::read::EXCERPT_CHARS`] characters of `text`, for an error.
fn excerpt(text: &str) -> String {
    format!("{:?}", limits::excerpt(text, crate::read::EXCERPT_CHARS))
}

/// `name:type field;type field;...`
pub(super) fn parse_format(text: &str) -> std::result::Result<(String, Vec<FieldDef>), String> {
    let (name, rest) = text
        .split_once(':')
        .ok_or_else(|| format!("format {} has no ':'", excerpt(text)))?;
    if name.is_empty() {
        return Err(format!("format {} has no name", excerpt(text)));
    }
    let mut fields = Vec::new();
    for part in rest.split(';').filter(|p| !p.is_empty()) {
        let (ty, fname) = part
            .split_once(' ')
            .ok_or_else(|| format!("field {} of format {} is not 'type name'", excerpt(part), excerpt(name)))?;
        let (base, count) = match ty.split_once('[') {
            Some((base, n)) => {
                let n = n
                    .strip_suffix(']')
                    .and_then(|n| n.parse::<u64>().ok())
                    .filter(|&n| n <= u64::from(u16::MAX))
                    .ok_or_else(|| {
                        format!(
                            "field {} of format {}: not an array size up to 65535",
                            excerpt(part),
                            excerpt(name)
                        )
                    })?;
                (base, n)
            }
            None => (ty, 1),
        };
        if base.is_empty() || fname.is_empty() {
            return Err(format!(
                "field {} of format {} is not 'type name'",
                excerpt(part),
                excerpt(name)
            ));
        }
        fields.push(FieldDef {
            base: base.to_string(),
            count,
            name: fname.to_string(),
        });
    }
    Ok((name.to_string(), fields))
}

/// Bytes of one element of type `base`.
fn type_size(
    base: &str,
    formats: &HashMap<String, Vec<FieldDef>>,
    sizes: &mut HashMap<String, u64>,
    depth: usize,
) -> std::result::Result<u64, String> {
    let primitive = match base {
        "int8_t" | "uint8_t" | "bool" | "char" => 1,
        "int16_t" | "uint16_t" => 2,
        "int32_t" | "uint32_t" | "float" => 4,
        "int64_t" | "uint64_t" | "double" => 8,
        _ => 0,
    };
    if primitive > 0 {
        return Ok(primitive);
    }
    if let Some(&n) = sizes.get(base) {
        return Ok(n);
    }
    if depth >= MAX_NESTING {
        return Err(format!(
            "formats nested deeper than {MAX_NESTING} levels at {} (a format that contains itself?)",
            excerpt(base)
        ));
    }
    let fields = formats
        .get(base)
        .ok_or_else(|| format!("type {} is neither a ULog type nor a format of the log", excerpt(base)))?;
    let mut total: u64 = 0;
    for f in fields {
        let one = type_size(&f.base, formats, sizes, depth + 1)?;
        total = total.saturating_add(one.saturating_mul(f.count));
    }
    sizes.insert(base.to_string(), total);
    Ok(total)
}

/// Finds the top-level field `name` of `topic`: its offset and element count, checking its type.
pub(super) fn locate(
    topic: &str,
    name: &str,
    want: &str,
    formats: &HashMap<String, Vec<FieldDef>>,
    sizes: &mut HashMap<String, u64>,
) -> std::result::Result<Option<At>, String> {
    let fields = formats
        .get(topic)
        .ok_or_else(|| format!("topic {topic} has no format"))?;
    let mut offset: u64 = 0;
    for f in fields {
        if f.name == name {
            if f.base != want {
                return Err(format!("{topic}.{name} is {}, not {want}", excerpt(&f.base)));
            }
            let offset = usize::try_from(offset)
                .ok()
                .filter(|&o| o <= usize::from(u16::MAX))
                .ok_or_else(|| format!("{topic}.{name} lies past the largest message"))?;
            return Ok(Some(At { offset, count: f.count }));
        }
        offset = offset.saturating_add(type_size(&f.base, formats, sizes, 1)?.saturating_mul(f.count));
    }
    Ok(None)
}

/// The decoder of a subscription to `topic`.
fn decoder(
    topic: Topic,
    multi_id: u8,
    formats: &HashMap<String, Vec<FieldDef>>,
    sizes: &mut HashMap<String, u64>,
) -> std::result::Result<Decoder, String> {
    let name = topic.name();
    let timestamp = locate(name, "timestamp", "uint64_t", formats, sizes)?
        .ok_or_else(|| format!("{name} has no timestamp"))?
        .offset;
    if matches!(topic, Topic::Gps | Topic::SensorGps) {
        let gps = gps_layout(name, formats, sizes)?;
        return Ok(Decoder {
            topic,
            multi_id,
            timestamp,
            values: [0; 4],
            n: 0,
            device_id: None,
            need: gps.need().max(timestamp + 8),
            gps: Some(gps),
        });
    }
    let (field, n, first) = topic.value_field();
    let mut values = [0usize; 4];
    if topic == Topic::SensorMag {
        for (k, axis) in ["x", "y", "z"].into_iter().enumerate() {
            values[k] = locate(name, axis, "float", formats, sizes)?
                .ok_or_else(|| format!("{name} has no field {axis}"))?
                .offset;
        }
    } else {
        let at = locate(name, field, "float", formats, sizes)?.ok_or_else(|| format!("{name} has no field {field}"))?;
        if at.count < first + n {
            return Err(format!(
                "{name}.{field} has {} elements, {} are read",
                at.count,
                first + n
            ));
        }
        for (k, v) in values.iter_mut().enumerate().take(n as usize) {
            *v = at.offset + 4 * (first as usize + k);
        }
    }
    let device_id = if matches!(topic, Topic::SensorMag | Topic::VehicleMagnetometer) {
        locate(name, "device_id", "uint32_t", formats, sizes)?.map(|a| a.offset)
    } else {
        None
    };
    let n = n as usize;
    let need = [timestamp + 8, device_id.map_or(0, |o| o + 4)]
        .into_iter()
        .chain(values[..n].iter().map(|o| o + 4))
        .max()
        .unwrap_or(0);
    Ok(Decoder {
        topic,
        multi_id,
        timestamp,
        values,
        n,
        device_id,
        gps: None,
        need,
    })
}

fn f32_at(data: &[u8], o: usize) -> f32 {
    f32::from_le_bytes(data[o..o + 4].try_into().expect("4 bytes"))
}

/// Decodes one data message of a kept topic (its length already checked against `d.need`).
fn keep(raw: &mut Raw, d: &Decoder, data: &[u8], at: u64, budget: &mut Budget, shown: &str) -> Result<()> {
    let t_us = u64::from_le_bytes(data[d.timestamp..d.timestamp + 8].try_into().expect("8 bytes"));
    let mut v = [0f32; 4];
    for (x, &o) in v.iter_mut().zip(&d.values[..d.n]) {
        *x = f32_at(data, o);
    }
    match d.topic {
        Topic::SensorMag | Topic::VehicleMagnetometer => {
            budget.charge(HELD_PER_READING, shown, at)?;
            let device_id = d
                .device_id
                .map(|o| u32::from_le_bytes(data[o..o + 4].try_into().expect("4 bytes")));
            let map = if d.topic == Topic::SensorMag {
                &mut raw.sensor_mag
            } else {
                &mut raw.vehicle_mag
            };
            map.entry(d.multi_id).or_default().push(RawReading {
                t_us,
                v: [v[0], v[1], v[2]],
                device_id,
                offset: at,
            });
        }
        Topic::Attitude => {
            // One attitude: the estimator's output, instance 0.
            if d.multi_id == 0 {
                budget.charge(HELD_PER_ATTITUDE, shown, at)?;
                raw.attitude.push((t_us, v, at));
            }
        }
        Topic::Battery => {
            budget.charge(HELD_PER_SCALAR, shown, at)?;
            raw.battery.entry(d.multi_id).or_default().push((t_us, v[0], at));
        }
        Topic::Controls => {
            if d.multi_id == 0 {
                budget.charge(HELD_PER_SCALAR, shown, at)?;
                raw.controls.push((t_us, v[0], at));
            }
        }
        Topic::Gps | Topic::SensorGps => {
            if let (0, Some(g)) = (d.multi_id, &d.gps) {
                budget.charge(HELD_PER_FIX, shown, at)?;
                let (list, headings) = if d.topic == Topic::Gps {
                    (&mut raw.vehicle_gps, &mut raw.vehicle_gps_heading)
                } else {
                    (&mut raw.sensor_gps, &mut raw.sensor_gps_heading)
                };
                let fix = g.fix(data);
                list.push((t_us, fix, at));
                if let Some(h) = g.heading.map(|o| f32_at(data, o)).filter(|h| h.is_finite())
                    && fix.fix_type >= 3
                {
                    headings.push((t_us, h, at));
                }
            }
        }
        Topic::Thrust => {
            if d.multi_id == 0 {
                budget.charge(HELD_PER_SCALAR, shown, at)?;
                let norm = (f64::from(v[0]).powi(2) + f64::from(v[1]).powi(2) + f64::from(v[2]).powi(2)).sqrt();
                raw.thrust.push((t_us, norm as f32, at));
            }
        }
    }
    Ok(())
}
