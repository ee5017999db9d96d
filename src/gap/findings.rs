//! What a localisation finds in the residual: significant intervals (over position or time),
//! periodogram peaks and other-axis line groups, each with its JSON and its sentence.
use csmetro_effects::AxisId;
use serde_json::{json, Value as Json};

/// One significant interval of the residual.
#[derive(Debug, Clone)]
pub struct Where {
    pub map: &'static str,
    pub axis: Option<AxisId>,
    pub direction: Option<&'static str>,
    pub component: Option<AxisId>,
    pub from: f64,
    pub to: f64,
    pub share: f64,
    pub z: f64,
    pub peak_um: f64,
}

impl Where {
    pub fn to_json(&self) -> Json {
        let (from_um, to_um, from_s, to_s) = match self.map {
            "time" => (None, None, Some(self.from), Some(self.to)),
            _ => (Some(self.from), Some(self.to), None, None),
        };
        json!({
            "map": self.map,
            "axis": self.axis.map(|a| a.as_str()),
            "direction": self.direction,
            "component": self.component.map(|a| a.as_str()),
            "from_um": from_um,
            "to_um": to_um,
            "from_s": from_s,
            "to_s": to_s,
            "share": self.share,
            "z": self.z,
            "peak_um": self.peak_um,
        })
    }

    pub fn describe(&self) -> String {
        match self.map {
            "time" => format!(
                "time {:.0}..{:.0} s (share {:.0} %, peak {:.3} µm)",
                self.from,
                self.to,
                100.0 * self.share,
                self.peak_um
            ),
            _ => format!(
                "{} lines, {}, {} component, {:.0}..{:.0} µm (share {:.0} %, peak {:.3} µm)",
                self.axis.map(|a| a.as_str()).unwrap_or("-"),
                self.direction.unwrap_or("-"),
                self.component.map(|a| a.as_str()).unwrap_or("-"),
                self.from,
                self.to,
                100.0 * self.share,
                self.peak_um
            ),
        }
    }
}

/// A significant periodogram peak of the residual over position.
#[derive(Debug, Clone)]
pub struct Peak {
    pub axis: AxisId,
    pub component: AxisId,
    pub period_um: f64,
    pub amplitude_um: f64,
    /// False-alarm probability (Bonferroni over the frequency grid).
    pub fap: f64,
}

impl Peak {
    pub fn describe(&self) -> String {
        format!(
            "periodic: {} lines, {} component, period {:.2} µm, amplitude {:.3} µm (false-alarm p {:.1e})",
            self.axis, self.component, self.period_um, self.amplitude_um, self.fap
        )
    }

    pub fn to_json(&self) -> Json {
        json!({
            "axis": self.axis.as_str(),
            "component": self.component.as_str(),
            "period_um": self.period_um,
            "amplitude_um": self.amplitude_um,
            "fap": self.fap,
        })
    }
}

/// Other-axis map: systematic residual per line group (moving axis, static position, component).
#[derive(Debug, Clone)]
pub struct OtherAxis {
    pub axis: AxisId,
    pub component: AxisId,
    /// Position of the static (other) axis, µm.
    pub static_um: f64,
    /// RMS of the systematic part (cell means in excess of the repeatability), µm.
    pub rms_um: f64,
    pub z: f64,
}

impl OtherAxis {
    pub fn to_json(&self) -> Json {
        json!({
            "axis": self.axis.as_str(),
            "component": self.component.as_str(),
            "static_um": self.static_um,
            "rms_um": self.rms_um,
            "z": self.z,
        })
    }
}
