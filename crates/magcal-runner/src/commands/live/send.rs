//! `live --send`: the first usable calibration sent to the vehicle as the ArduPilot parameters
//! `export --to ardupilot` writes, each by `PARAM_SET` over the link it streams on, read back from
//! the `PARAM_VALUE` the autopilot answers with, and compared.

use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use mavlink::dialects::ardupilotmega::{MavMessage, MavParamType, PARAM_SET_DATA};
use mavlink::{MavHeader, MavlinkVersion, write_versioned_msg};
use serde::Serialize;

use super::source::{Link, Shared};

/// How long the vehicle has to answer every parameter (one resend of the unanswered half-way).
const ANSWER: Duration = Duration::from_secs(6);

/// What came back of the parameters sent.
#[derive(Debug, Clone, Serialize)]
pub struct SentJson {
    /// The vehicle's system and component.
    pub system: u8,
    pub component: u8,
    /// Every parameter sent, with its value.
    pub parameters: Vec<(String, f32)>,
    /// Read back with the value sent.
    pub equal: Vec<String>,
    /// Read back with another value: name, sent, read back.
    pub differ: Vec<(String, f32, f32)>,
    /// Not read back within the time allowed.
    pub missing: Vec<String>,
}

impl SentJson {
    /// Whether the vehicle holds every value sent.
    pub fn confirmed(&self) -> bool {
        self.differ.is_empty() && self.missing.is_empty()
    }

    /// One sentence.
    pub fn words(&self) -> String {
        let mut s = format!(
            "sent {} parameters to system {} component {}: {} read back equal",
            self.parameters.len(),
            self.system,
            self.component,
            self.equal.len()
        );
        for (name, sent, back) in &self.differ {
            s += &format!("; {name} reads back {back} (sent {sent})");
        }
        if !self.missing.is_empty() {
            s += &format!(
                "; not answered within {} s: {}",
                ANSWER.as_secs(),
                self.missing.join(", ")
            );
        }
        s
    }
}

/// The parameters of an ArduPilot export's text (`NAME,VALUE` lines; `#` starts a comment).
///
/// # Errors
/// A line that is neither.
pub fn parameters(export: &str) -> Result<Vec<(String, f32)>> {
    let mut out = Vec::new();
    for line in export
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with('#'))
    {
        let (name, value) = line
            .split_once(',')
            .with_context(|| format!("export line {line:?}: not NAME,VALUE"))?;
        let value: f64 = value
            .trim()
            .parse()
            .with_context(|| format!("export line {line:?}: not a number"))?;
        out.push((name.trim().to_string(), value as f32));
    }
    if out.is_empty() {
        bail!("the export holds no parameter");
    }
    Ok(out)
}

/// Whether `back` is the value `sent`, bit for bit as a 32-bit float (but for the sign of a
/// zero: a parameter of integer type comes back as the float of its integer, +0 for -0).
fn same(sent: f32, back: f32) -> bool {
    sent == back
}

/// Sends `parameters` to the vehicle over `link` and reads them back.
///
/// # Errors
/// No vehicle identified yet (no autopilot's `HEARTBEAT` with compass frames), several
/// autopilots with compass frames where `--vehicle` did not choose one, or the link cannot be
/// written.
pub fn send(link: &mut Link, shared: &Shared, parameters: &[(String, f32)]) -> Result<SentJson> {
    let (vehicle, peer, contested) = {
        let s = shared.lock();
        (s.vehicle, s.peer(), s.contested())
    };
    let (system, component) =
        vehicle.context("no autopilot's HEARTBEAT came with compass frames: the vehicle is unknown")?;
    if !contested.is_empty() {
        let others: Vec<String> = contested.iter().map(|(s, c)| format!("{s}:{c}")).collect();
        bail!(
            "autopilots {system}:{component} and {} all send compass frames: choose the vehicle with --vehicle SYSTEM[:COMPONENT]",
            others.join(", ")
        );
    }
    let header = MavHeader {
        system_id: 255,
        component_id: 190,
        sequence: 0,
    };
    let started = Instant::now();
    let put = |link: &mut Link, (name, value): &(String, f32)| -> Result<()> {
        let msg = MavMessage::PARAM_SET(PARAM_SET_DATA {
            param_value: *value,
            target_system: system,
            target_component: component,
            param_id: name.as_str().into(),
            param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
        });
        let mut bytes = Vec::new();
        write_versioned_msg(&mut bytes, MavlinkVersion::V2, header, &msg)?;
        link.send(&bytes, peer).with_context(|| format!("sending {name}"))
    };
    for p in parameters {
        put(link, p)?;
    }
    // Only the vehicle's own PARAM_VALUE, after the PARAM_SET, confirms.
    let answered = |name: &str| {
        let s = shared.lock();
        s.heard
            .get(&(system, component))
            .and_then(|h| h.params.get(name))
            .filter(|(_, at)| *at >= started)
            .map(|(v, _)| *v)
    };
    let mut resent = false;
    loop {
        let missing: Vec<&(String, f32)> = parameters.iter().filter(|(n, _)| answered(n).is_none()).collect();
        if missing.is_empty() || started.elapsed() >= ANSWER {
            break;
        }
        if !resent && started.elapsed() >= ANSWER / 2 {
            resent = true;
            for p in missing {
                put(link, p)?;
            }
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let mut sent = SentJson {
        system,
        component,
        parameters: parameters.to_vec(),
        equal: Vec::new(),
        differ: Vec::new(),
        missing: Vec::new(),
    };
    for (name, value) in parameters {
        match answered(name) {
            Some(back) if same(*value, back) => sent.equal.push(name.clone()),
            Some(back) => sent.differ.push((name.clone(), *value, back)),
            None => sent.missing.push(name.clone()),
        }
    }
    Ok(sent)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_ardupilot_export_gives_its_parameters() {
        let text = "# magcal export\n# keeps\nCOMPASS_OFS_X,-30.5\nCOMPASS_DIA_X,1.0123456789\nCOMPASS_MOTCT,0\n";
        let p = parameters(text).unwrap();
        assert_eq!(
            p,
            vec![
                ("COMPASS_OFS_X".to_string(), -30.5),
                ("COMPASS_DIA_X".to_string(), 1.012_345_7),
                ("COMPASS_MOTCT".to_string(), 0.0)
            ]
        );
        assert!(parameters("# only comments\n").is_err());
        assert!(parameters("COMPASS_OFS_X -30\n").is_err());
        assert!(same(1.012_345_7, 1.012_345_7) && !same(1.0, 1.001) && same(0.0, -0.0));
        // One unit in the last place of a float apart is not the value sent.
        let x = 91.8f32;
        assert!(!same(x, f32::from_bits(x.to_bits() + 1)));
    }
}
