//! The lab's truth on disk: every line the board received, every exposure with its tip,
//! the clients, and `lab.json` (see the module docs of [`super`]).

use std::path::Path;
use std::sync::Arc;

use super::stream::Stream;
use super::{write, LabConfig, LabError, LabSummary, Shared, LAMP_MM};
use crate::provenance::Provenance;
use crate::stereo::Side;

/// The truth's files (see the module docs).
pub(super) struct TruthFiles<'a> {
    pub(super) dir: &'a Path,
    pub(super) config: &'a LabConfig,
    pub(super) provenance: &'a Provenance,
    pub(super) epoch_unix_s: f64,
    pub(super) streams: &'a [Arc<Stream>],
}

impl TruthFiles<'_> {
    pub(super) fn write(&self, shared: &Shared) -> Result<LabSummary, LabError> {
        let mut summary = LabSummary {
            seconds: shared.now_s(),
            ..LabSummary::default()
        };
        let received = shared.received.lock().expect("received").clone();
        summary.lines_received = received.iter().filter(|r| r.line != "(watchdog)").count();
        let mut csv = csv::Writer::from_writer(Vec::new());
        let rows = std::iter::once(["time_s".to_string(), "line".into(), "reply".into()]).chain(
            received
                .iter()
                .map(|r| [format!("{:.6}", r.time_s), r.line.clone(), r.reply.clone()]),
        );
        for row in rows {
            csv.write_record(&row).expect("in memory");
        }
        let text = String::from_utf8(csv.into_inner().expect("in memory")).expect("utf-8");
        write(&self.dir.join("received.csv"), &text)?;

        let mut exposed = shared.exposed.lock().expect("exposed").clone();
        exposed.sort_by(|a, b| {
            (a.camera as u8, a.exposure_s)
                .partial_cmp(&(b.camera as u8, b.exposure_s))
                .expect("finite")
        });
        let mut text =
            String::from("camera,exposure_s,frame,sent_s,late_ms,x_mm,y_mm,z_mm,u_px,v_px,lamp\n");
        for e in &exposed {
            let k = e.camera as usize;
            summary.exposed[k] += 1;
            let (sent, frame) = match e.sent {
                Some((t, n)) => {
                    summary.sent[k] += 1;
                    (format!("{t:.6}"), n.to_string())
                }
                None => {
                    summary.lost[k] += 1;
                    (String::new(), String::new())
                }
            };
            if e.late_s > 0.0 {
                summary.late += 1;
                summary.worst_late_ms = summary.worst_late_ms.max(e.late_s * 1e3);
            }
            let [u, v] = e.tip_px.map_or([String::new(), String::new()], |p| {
                p.map(|x| format!("{x:.4}"))
            });
            let [x, y, z] = e.tip_mm;
            text += &format!(
                "{},{:.6},{frame},{sent},{:.3},{x:.5},{y:.5},{z:.5},{u},{v},{:.4}\n",
                e.camera.name(),
                e.exposure_s,
                e.late_s * 1e3,
                e.lamp
            );
        }
        write(&self.dir.join("frames.csv"), &text)?;

        let mut text = String::from("camera,connected_s,first_frame,frames_sent\n");
        for (side, stream) in [Side::Left, Side::Right].iter().zip(self.streams) {
            for c in stream.clients() {
                text += &format!(
                    "{},{:.6},{},{}\n",
                    side.name(),
                    c.connected_s,
                    c.first,
                    c.sent
                );
            }
        }
        write(&self.dir.join("clients.csv"), &text)?;

        let json = serde_json::json!({
            "format": "handcap-lab/1",
            "epoch_unix_s": self.epoch_unix_s,
            "config": self.config,
            "lamp_mm": LAMP_MM,
            "summary": summary,
            "provenance": self.provenance,
        });
        let text = serde_json::to_string_pretty(&json).expect("json") + "\n";
        write(&self.dir.join("lab.json"), &text)?;
        Ok(summary)
    }
}
