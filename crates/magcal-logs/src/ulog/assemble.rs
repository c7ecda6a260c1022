//! From the records of a ULog ([`super::Raw`]) to the [`Px4Log`] of one instance: the instance
//! chosen and matched to its calibration slot, the firmware's calibration undone where the log
//! predates raw logging, the series logged beside the readings, and the notes.

use super::*;

/// Turns `raw` into the [`Px4Log`] of `selection`'s instance.
pub(super) fn assemble(raw: Raw, shown: &str, selection: &Selection, sha256: String, bytes: u64) -> Result<Px4Log> {
    let chosen = choose_instance(&raw, shown, selection)?;
    let mut notes = Vec::new();
    let mut messages = Vec::new();
    let ver = raw.info_u32.get("ver_sw_release").copied().filter(|&v| v != 0);
    match ver {
        Some(v) => messages.push(format!("info: ver_sw_release 0x{v:08X} = {}", version_words(v))),
        None => notes.push("The log has no firmware version (info ver_sw_release).".to_string()),
    }
    let slot = match_slot(&raw, &chosen, &mut notes);
    let (calibration, frame, samples) = carried(&raw, &chosen, &slot, ver, shown, &mut notes)?;
    messages.insert(0, chosen.source());
    if let Some(p) = &slot.prefix {
        messages.push(format!("parameters: {p}* (matched by {})", slot.matched_by));
    }
    let to_body = if !chosen.from_sensor {
        Some([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    } else {
        body_rotation(
            slot.cal("ROT"),
            &slot.parameters,
            slot.prefix.as_deref(),
            &raw,
            &mut notes,
        )
    };
    let comp_type = slot.parameters.get("CAL_MAG_COMP_TYP").copied().unwrap_or(0.0);
    note_compensation(&slot, comp_type, &mut notes);
    let beside = beside(&raw, shown, comp_type, &mut messages)?;
    let rate_hz = rate_of(&samples);
    note_rate(&raw, &chosen, &samples, rate_hz, beside.attitude.as_ref(), &mut notes);
    note_file(&raw, &mut notes);
    // A ULog's header holds every parameter of its firmware.
    let parameters = LogParameters::px4(raw.initial.keys());
    let log = FlightLog {
        format: Format::Ulog,
        messages,
        unit: Units::Gauss,
        frame,
        instances: chosen.instances,
        instance: chosen.instance,
        samples,
        attitude: beside.attitude,
        current: beside.current,
        throttle: beside.throttle,
        gps: beside.gps,
        gps_yaw: beside.gps_yaw,
        gsf_yaw: None,
        to_body,
        calibration,
        notes,
        parameters,
        sha256,
        bytes,
    };
    Ok(Px4Log {
        log,
        calibration_index: slot.index,
        matched_by: slot.matched_by,
        parameters: slot.parameters,
        ver_sw_release: ver,
        rate_hz,
    })
}

/// The magnetometer series read: `sensor_mag`, else `vehicle_magnetometer`, and its instance.
struct Chosen<'a> {
    /// Whether the readings are `sensor_mag`'s.
    from_sensor: bool,
    topic: &'static str,
    /// The instances the log has of `topic`, ascending.
    instances: Vec<u8>,
    instance: u8,
    /// The instance's readings, at least one.
    readings: &'a [RawReading],
}

impl Chosen<'_> {
    /// The `device_id` of the first reading, where the topic carries one.
    fn device_id(&self) -> Option<u32> {
        self.readings[0].device_id
    }

    /// What was read, for the log's messages.
    fn source(&self) -> String {
        format!(
            "{} (multi_id {}{}): {}",
            self.topic,
            self.instance,
            self.device_id().map_or(String::new(), |id| format!(", device_id {id}")),
            if self.from_sensor {
                "x, y, z"
            } else {
                "magnetometer_ga[0..2]"
            }
        )
    }
}

/// The series of `selection`'s instance (default the lowest), or an error naming those there are.
fn choose_instance<'a>(raw: &'a Raw, shown: &str, selection: &Selection) -> Result<Chosen<'a>> {
    let from_sensor = !raw.sensor_mag.is_empty();
    let series = if from_sensor { &raw.sensor_mag } else { &raw.vehicle_mag };
    if series.is_empty() {
        bail!("{shown}: the log has no magnetometer readings (no sensor_mag or vehicle_magnetometer data)");
    }
    let topic = if from_sensor {
        "sensor_mag"
    } else {
        "vehicle_magnetometer"
    };
    let instances: Vec<u8> = series.keys().copied().collect();
    let instance = selection.instance.unwrap_or(instances[0]);
    let Some(readings) = series.get(&instance) else {
        let list: Vec<String> = instances.iter().map(u8::to_string).collect();
        bail!(
            "{shown}: --compass {instance}: the log has {topic} instance{} {} only",
            if list.len() == 1 { "" } else { "s" },
            list.join(", ")
        );
    };
    Ok(Chosen {
        from_sensor,
        topic,
        instances,
        instance,
        readings,
    })
}

/// The `CAL_MAGn_*` slot matched to the instance read, and the parameters kept.
struct Slot {
    /// The `n` matched, if any.
    index: Option<u8>,
    /// How `n` was matched, in words.
    matched_by: String,
    /// `CAL_MAGn_` of the `n` matched.
    prefix: Option<String>,
    /// See [`Px4Log::parameters`].
    parameters: BTreeMap<String, f64>,
}

impl Slot {
    /// `CAL_MAGn_{suffix}` of the slot matched, where logged.
    fn cal(&self, suffix: &str) -> Option<f64> {
        self.prefix
            .as_ref()
            .and_then(|p| self.parameters.get(&format!("{p}{suffix}")).copied())
    }
}

/// The calibration slot of the instance read, with notes on a change of sensor or of the slot's
/// parameters inside the log.
fn match_slot(raw: &Raw, chosen: &Chosen<'_>, notes: &mut Vec<String>) -> Slot {
    let (index, matched_by) = slot_index(raw, chosen);
    if let Some(id) = chosen.device_id()
        && let Some(other) = chosen.readings.iter().find(|r| r.device_id != Some(id))
    {
        notes.push(format!(
            "{} instance {} changes device_id from {id} to {} at byte {}: another sensor took its place.",
            chosen.topic,
            chosen.instance,
            other.device_id.unwrap_or(0),
            other.offset
        ));
    }
    let prefix = index.map(|n| format!("CAL_MAG{n}_"));
    let parameters = kept_parameters(raw, prefix.as_deref());
    if let Some(p) = &prefix {
        note_changes(raw, p, notes);
    }
    Slot {
        index,
        matched_by,
        prefix,
        parameters,
    }
}

/// The `n` of `CAL_MAGn_*`: by `CAL_MAGn_ID == device_id`, else the instance number where
/// `CAL_MAGn_XOFF` is logged; and how, in words.
fn slot_index(raw: &Raw, chosen: &Chosen<'_>) -> (Option<u8>, String) {
    let device_id = chosen.device_id();
    let param = |name: &str| raw.initial.get(name).copied();
    if let Some(id) = device_id {
        for n in 0..10u8 {
            if let Some(Param::Int(v)) = param(&format!("CAL_MAG{n}_ID"))
                && v as u32 == id
            {
                return (Some(n), format!("CAL_MAG{n}_ID = device_id {id}"));
            }
        }
    }
    let instance = chosen.instance;
    if param(&format!("CAL_MAG{instance}_XOFF")).is_some() {
        let words = match device_id {
            Some(id) => format!("instance number (no CAL_MAGn_ID equals device_id {id})"),
            None => format!("instance number ({} carries no device_id)", chosen.topic),
        };
        return (Some(instance), words);
    }
    (None, String::from("no CAL_MAGn_* parameters in the log"))
}

/// The parameters in force at the start that bear on the calibration: `CAL_MAGn_*` of `prefix`,
/// `CAL_MAG_COMP_TYP`, `SENS_BOARD_ROT`, `SENS_BOARD_*_OFF`.
fn kept_parameters(raw: &Raw, prefix: Option<&str>) -> BTreeMap<String, f64> {
    let mut parameters = BTreeMap::new();
    for (k, v) in &raw.initial {
        let wanted = prefix.is_some_and(|p| k.starts_with(p))
            || k == "CAL_MAG_COMP_TYP"
            || k == "SENS_BOARD_ROT"
            || (k.starts_with("SENS_BOARD_") && k.ends_with("_OFF"));
        if wanted {
            parameters.insert(k.clone(), v.value());
        }
    }
    parameters
}

/// A note where the parameters of `prefix` change inside the log.
fn note_changes(raw: &Raw, prefix: &str, notes: &mut Vec<String>) {
    let changed: Vec<&str> = raw
        .changes
        .iter()
        .filter(|(_, k, v)| k.starts_with(prefix) && raw.initial.get(k) != Some(v))
        .map(|(_, k, _)| k.as_str())
        .collect();
    if !changed.is_empty() {
        notes.push(format!(
            "{} change{} of {prefix}* inside the log (first {}); the values in force at each reading are used.",
            changed.len(),
            if changed.len() == 1 { "" } else { "s" },
            changed[0]
        ));
    }
}

/// What the readings carry, the frame they are in, and the readings.
type Carried = (InForce, String, Vec<Sample>);

/// What the readings carry, by topic and firmware version `ver` (see the module docs), and the
/// readings: raw, undone, or as logged.
fn carried(
    raw: &Raw,
    chosen: &Chosen<'_>,
    slot: &Slot,
    ver: Option<u32>,
    shown: &str,
    notes: &mut Vec<String>,
) -> Result<Carried> {
    let (readings, topic) = (chosen.readings, chosen.topic);
    if !chosen.from_sensor {
        let words = format!(
            "vehicle_magnetometer: PX4 publishes it after its calibration in force{} and rotated into the body frame; a fit calibrates the calibrated field",
            slot.index.map_or(String::new(), |n| format!(" (CAL_MAG{n}_*)"))
        );
        notes.push(
            "The log has no sensor_mag: read vehicle_magnetometer, which PX4 calibrates before it logs it.".to_string(),
        );
        return Ok((
            InForce::Calibrated(words),
            "body (forward, right, down)".to_string(),
            plain(readings, shown, topic)?,
        ));
    }
    match ver.map(|v| (v >> 16) >= 0x010C) {
        Some(true) => Ok((InForce::Raw, "sensor".to_string(), plain(readings, shown, topic)?)),
        None => {
            let words = "the log has no firmware version: sensor_mag is raw from PX4 1.12 on and calibrated before, which cannot be told here; read as logged".to_string();
            Ok((
                InForce::Calibrated(words),
                "sensor (as logged)".to_string(),
                plain(readings, shown, topic)?,
            ))
        }
        Some(false) => undo_driver(raw, chosen, slot, shown),
    }
}

/// `sensor_mag` of PX4 before 1.12, which its driver calibrated: undone where the log has the
/// slot's offsets and scales, else as logged.
fn undo_driver(raw: &Raw, chosen: &Chosen<'_>, slot: &Slot, shown: &str) -> Result<Carried> {
    let readings = chosen.readings;
    match slot.prefix.as_ref().and_then(|p| old_calibration(p, raw)) {
        Some(cal0) => {
            let p = slot.prefix.as_deref().unwrap_or_default();
            let samples = undo(readings, raw, p, cal0, shown)?;
            let words = format!(
                "PX4 before 1.12 logs sensor_mag after its driver applied m = SCALE * (r - OFF) per axis; undone with {p}XOFF..ZOFF and {p}XSCALE..ZSCALE in force at each reading (n matched by {})",
                slot.matched_by
            );
            Ok((
                InForce::Undone(words),
                "sensor (after the driver's orientation)".to_string(),
                samples,
            ))
        }
        None => {
            let words = format!(
                "PX4 before 1.12 logs sensor_mag after its driver's calibration, and the log lacks {}XOFF..ZOFF or XSCALE..ZSCALE (finite, scales not zero) to undo it",
                slot.prefix.as_deref().unwrap_or("CAL_MAGn_")
            );
            Ok((
                InForce::Calibrated(words),
                "sensor (calibrated by the driver)".to_string(),
                plain(readings, shown, chosen.topic)?,
            ))
        }
    }
}

/// A note where the slot has a power compensation, which the raw field does not carry.
fn note_compensation(slot: &Slot, comp_type: f64, notes: &mut Vec<String>) {
    let comp = ["XCOMP", "YCOMP", "ZCOMP"].map(|k| slot.cal(k).unwrap_or(0.0));
    if comp.iter().any(|&c| c != 0.0) {
        notes.push(format!(
            "PX4 adds power * ({}, {}, {}) (CAL_MAG_COMP_TYP = {comp_type}) to the field before its calibration; the readings here are without it.",
            comp[0], comp[1], comp[2]
        ));
    }
}

/// The series logged beside the readings.
struct Beside {
    attitude: Option<Series<[f64; 4]>>,
    current: Option<Series<f64>>,
    throttle: Option<Series<f64>>,
    gps: Option<Series<Fix>>,
    gps_yaw: Option<(Series<f64>, String)>,
}

/// The attitude, the current of the battery `CAL_MAG_COMP_TYP` = `comp_type` names, and the
/// throttle, each named in `messages` where the log has it.
fn beside(raw: &Raw, shown: &str, comp_type: f64, messages: &mut Vec<String>) -> Result<Beside> {
    let attitude = series_of(&raw.attitude, shown, "vehicle_attitude", |q| {
        [f64::from(q[0]), f64::from(q[1]), f64::from(q[2]), f64::from(q[3])]
    })?;
    if attitude.is_some() {
        messages.push("vehicle_attitude (multi_id 0): q[0..3] (w, x, y, z; body FRD to NED)".to_string());
    }
    let battery_instance = if comp_type == 3.0 { 1 } else { 0 };
    let current = match raw.battery.get(&battery_instance) {
        Some(b) => {
            messages.push(format!("battery_status (multi_id {battery_instance}): current_a (A)"));
            series_of(b, shown, "battery_status", f64::from)?
        }
        None => None,
    };
    let throttle = if !raw.controls.is_empty() {
        messages.push("actuator_controls_0: control[3] (throttle)".to_string());
        series_of(&raw.controls, shown, "actuator_controls_0", f64::from)?
    } else if !raw.thrust.is_empty() {
        messages.push("vehicle_thrust_setpoint (multi_id 0): |xyz| (throttle)".to_string());
        series_of(&raw.thrust, shown, "vehicle_thrust_setpoint", f64::from)?
    } else {
        None
    };
    let (topic, fixes, headings) = if raw.vehicle_gps.is_empty() {
        ("sensor_gps", &raw.sensor_gps, &raw.sensor_gps_heading)
    } else {
        ("vehicle_gps_position", &raw.vehicle_gps, &raw.vehicle_gps_heading)
    };
    let gps_yaw = series_of(headings, shown, topic, |h| f64::from(h).to_degrees().rem_euclid(360.0))?
        .map(|s| (s, format!("{topic}.heading (moving baseline)")));
    let gps = series_of(fixes, shown, topic, |f| f)?;
    if gps.is_some() {
        messages.push(format!(
            "{topic} (multi_id 0): fix_type, latitude, longitude, altitude (mean sea level), time_utc_usec"
        ));
    }
    Ok(Beside {
        attitude,
        current,
        throttle,
        gps,
        gps_yaw,
    })
}

/// Readings per second: (readings - 1) / time spanned; 0 for one reading or no time spanned.
fn rate_of(samples: &[Sample]) -> f64 {
    let span = samples.last().map_or(0.0, |l| l.time_s) - samples[0].time_s;
    if samples.len() > 1 && span > 0.0 {
        (samples.len() - 1) as f64 / span
    } else {
        0.0
    }
}

/// Notes where the readings are too few or too slow to calibrate (see the module docs), and
/// where `vehicle_magnetometer` then holds more of them.
fn note_rate(
    raw: &Raw,
    chosen: &Chosen<'_>,
    samples: &[Sample],
    rate_hz: f64,
    attitude: Option<&Series<[f64; 4]>>,
    notes: &mut Vec<String>,
) {
    let topic = chosen.topic;
    let turn = attitude.map(peak_turn_rate);
    let how = "raise it with SDLOG_PROFILE (add 64, sensor comparison: sensor_mag at 10 Hz) or a line 'sensor_mag 20' in the SD card's etc/logging/logger_topics.txt (50 Hz)";
    if samples.len() < MIN_READINGS {
        notes.push(format!(
            "Only {} {topic} readings ({rate_hz:.2} Hz): fewer than {MIN_READINGS}, too few to calibrate; {how}.",
            samples.len()
        ));
    } else if rate_hz < MIN_RATE_HZ {
        let moving = match turn {
            Some(t) if t >= TURNING_DEG_S => format!(
                "while the vehicle turns at up to {t:.0} degrees per second ({:.0} degrees between readings)",
                t / rate_hz
            ),
            Some(t) => format!(
                "(the vehicle turns at most {t:.0} degrees per second in this log; a calibration flight turns faster)"
            ),
            None => "(the log has no attitude to tell how fast the vehicle turns)".to_string(),
        };
        notes.push(format!(
            "{topic} is logged at {rate_hz:.2} Hz {moving}: below {MIN_RATE_HZ} Hz, too slow to calibrate (PX4's default logging profile records it at 1 Hz); {how}."
        ));
    }
    if chosen.from_sensor
        && rate_hz < MIN_RATE_HZ
        && let Some(v) = raw
            .vehicle_mag
            .get(&chosen.instance)
            .or_else(|| raw.vehicle_mag.values().next())
        && v.len() > samples.len()
    {
        notes.push(format!(
            "vehicle_magnetometer holds {} readings (calibrated by PX4, body frame) against {} of sensor_mag.",
            v.len(),
            samples.len()
        ));
    }
}

/// Notes on what the pass over the file met: dropouts, messages of unknown types, bytes skipped
/// before appended data, a file version newer than this reader knows.
fn note_file(raw: &Raw, notes: &mut Vec<String>) {
    if raw.dropouts > 0 {
        notes.push(format!(
            "The logger dropped data {} times ({} ms in all).",
            raw.dropouts, raw.dropout_ms
        ));
    }
    for (t, n) in &raw.unknown {
        notes.push(format!(
            "Skipped {n} messages of a type this reader does not know ('{}').",
            char::from(*t)
        ));
    }
    if raw.skipped_before_appended > 0 {
        notes.push(format!(
            "Skipped {} bytes cut short before the appended data.",
            raw.skipped_before_appended
        ));
    }
    if raw.version > 1 {
        notes.push(format!(
            "ULog file version {} (this reader knows 0 and 1).",
            raw.version
        ));
    }
}

/// The readings as logged.
fn plain(readings: &[RawReading], shown: &str, topic: &str) -> Result<Vec<Sample>> {
    let mut out = Vec::with_capacity(readings.len());
    let mut last = 0u64;
    for r in readings {
        check_reading(r, last, shown, topic)?;
        last = r.t_us;
        out.push(Sample {
            time_s: r.t_us as f64 * 1e-6,
            raw: r.v.map(f64::from),
            offset: r.offset,
        });
    }
    Ok(out)
}

fn check_reading(r: &RawReading, last: u64, shown: &str, topic: &str) -> Result<()> {
    if r.v.iter().any(|x| !x.is_finite()) {
        bail!(
            "{shown}: byte {}: {topic} reading ({}, {}, {}) is not finite",
            r.offset,
            r.v[0],
            r.v[1],
            r.v[2]
        );
    }
    if r.t_us < last {
        bail!(
            "{shown}: byte {}: {topic} timestamp {} us is earlier than the one before ({last} us)",
            r.offset,
            r.t_us
        );
    }
    Ok(())
}

/// Offsets and scales of a calibration slot.
type OldCal = ([f64; 3], [f64; 3]);

/// `prefix`'s offsets and scales at the start of the log, where all six are logged and usable.
fn old_calibration(prefix: &str, raw: &Raw) -> Option<OldCal> {
    let get = |k: &str| raw.initial.get(&format!("{prefix}{k}")).map(|v| v.value());
    let off = [get("XOFF")?, get("YOFF")?, get("ZOFF")?];
    let scale = [get("XSCALE")?, get("YSCALE")?, get("ZSCALE")?];
    usable(&off, &scale).then_some((off, scale))
}

fn usable(off: &[f64; 3], scale: &[f64; 3]) -> bool {
    off.iter().chain(scale).all(|v| v.is_finite()) && scale.iter().all(|&s| s != 0.0)
}

/// `r = m / SCALE + OFF` per axis with the values in force at each reading.
fn undo(readings: &[RawReading], raw: &Raw, prefix: &str, mut cal: OldCal, shown: &str) -> Result<Vec<Sample>> {
    let keys = ["XOFF", "YOFF", "ZOFF", "XSCALE", "YSCALE", "ZSCALE"].map(|k| format!("{prefix}{k}"));
    let mut changes = raw.changes.iter().filter(|(_, k, _)| keys.contains(k)).peekable();
    let mut out = Vec::with_capacity(readings.len());
    let mut last = 0u64;
    for r in readings {
        check_reading(r, last, shown, "sensor_mag")?;
        last = r.t_us;
        while let Some((at, k, v)) = changes.next_if(|(at, _, _)| *at < r.offset) {
            let i = keys.iter().position(|x| x == k).expect("filtered on keys");
            let mut next = cal;
            if i < 3 {
                next.0[i] = v.value();
            } else {
                next.1[i - 3] = v.value();
            }
            if !usable(&next.0, &next.1) {
                bail!(
                    "{shown}: byte {at}: {k} = {} cannot be undone (not finite, or a zero scale)",
                    v.value()
                );
            }
            cal = next;
        }
        let (off, scale) = cal;
        out.push(Sample {
            time_s: r.t_us as f64 * 1e-6,
            raw: std::array::from_fn(|k| f64::from(r.v[k]) / scale[k] + off[k]),
            offset: r.offset,
        });
    }
    Ok(out)
}

/// The rotation PX4 applies to the sensor's calibrated field (see the module docs).
fn body_rotation(
    rot: Option<f64>,
    parameters: &BTreeMap<String, f64>,
    prefix: Option<&str>,
    raw: &Raw,
    notes: &mut Vec<String>,
) -> Option<Mat3> {
    let Some(rot) = rot else {
        notes.push(
            "The log has no CAL_MAGn_ROT for this sensor: its rotation into the body frame is unknown.".to_string(),
        );
        return None;
    };
    let p = prefix.unwrap_or_default();
    let level = euler_dcm(
        parameters.get("SENS_BOARD_X_OFF").copied().unwrap_or(0.0),
        parameters.get("SENS_BOARD_Y_OFF").copied().unwrap_or(0.0),
        parameters.get("SENS_BOARD_Z_OFF").copied().unwrap_or(0.0),
    );
    let rot = rot as i64;
    let sensor = if rot == -1 {
        let board = parameters.get("SENS_BOARD_ROT").copied().unwrap_or(0.0) as i64;
        let m = rotation_matrix(board);
        if m.is_none() {
            notes.push(format!(
                "SENS_BOARD_ROT = {board} is not a rotation this reader knows (PX4's enum Rotation, 0 to 47): the rotation into the body frame is unknown."
            ));
        }
        m
    } else if rot == ROTATION_CUSTOM {
        let angle = |k: &str| raw.initial.get(&format!("{p}{k}")).map(|v| v.value());
        match (angle("ROLL"), angle("PITCH"), angle("YAW")) {
            (Some(r), Some(pi), Some(y)) => Some(euler_dcm(r, pi, y)),
            _ => {
                notes.push(format!(
                    "{p}ROT = 100 (custom) without {p}ROLL, PITCH, YAW in the log: the rotation into the body frame is unknown."
                ));
                None
            }
        }
    } else {
        let m = rotation_matrix(rot);
        if m.is_none() {
            notes.push(format!(
                "{p}ROT = {rot} is not a rotation this reader knows (PX4's enum Rotation, 0 to 47, or 100): the rotation into the body frame is unknown."
            ));
        }
        m
    };
    sensor.map(|m| mat_mul(&level, &m))
}

/// A kept series as [`Series`], its times checked not to decrease; non-finite values dropped.
fn series_of<V: Copy, T>(
    points: &[(u64, V, u64)],
    shown: &str,
    topic: &str,
    f: impl Fn(V) -> T,
) -> Result<Option<Series<T>>>
where
    T: Finite,
{
    let mut out = Series {
        times: Vec::with_capacity(points.len()),
        values: Vec::with_capacity(points.len()),
    };
    let mut last = 0u64;
    for &(t, v, at) in points {
        if t < last {
            bail!("{shown}: byte {at}: {topic} timestamp {t} us is earlier than the one before ({last} us)");
        }
        last = t;
        let value = f(v);
        if value.finite() {
            out.times.push(t as f64 * 1e-6);
            out.values.push(value);
        }
    }
    Ok((!out.times.is_empty()).then_some(out))
}

/// Values whose every component is finite.
trait Finite {
    fn finite(&self) -> bool;
}

impl Finite for Fix {
    /// A fix without a position (NaN before the first one in some firmware) is still a fix:
    /// [`Fix::usable`] tells it apart.
    fn finite(&self) -> bool {
        true
    }
}

impl Finite for f64 {
    fn finite(&self) -> bool {
        self.is_finite()
    }
}

impl Finite for [f64; 4] {
    fn finite(&self) -> bool {
        self.iter().all(|x| x.is_finite())
    }
}

/// The fastest turn of the vehicle, degrees per second: the angle between attitudes at least
/// half a second apart over their time apart, at its largest.
fn peak_turn_rate(att: &Series<[f64; 4]>) -> f64 {
    let mut best: f64 = 0.0;
    let mut j = 0;
    for i in 0..att.times.len() {
        while j < att.times.len() && att.times[j] - att.times[i] < 0.5 {
            j += 1;
        }
        if j == att.times.len() {
            break;
        }
        let (a, b) = (att.values[i], att.values[j]);
        let dot = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]).abs();
        let na = a.iter().map(|x| x * x).sum::<f64>().sqrt();
        let nb = b.iter().map(|x| x * x).sum::<f64>().sqrt();
        if na > 0.0 && nb > 0.0 {
            let angle = 2.0 * (dot / (na * nb)).min(1.0).acos();
            best = best.max(angle.to_degrees() / (att.times[j] - att.times[i]));
        }
    }
    best
}
