//! The Tune panel's part of the machine thread: `nc-send tune`'s own code
//! ([`crate::scope::tune::load`], [`crate::scope::tune::tune`]) run on the station's
//! link between jobs, under the job's hooks (a page's Stop, Hold or E-STOP stops the
//! test signal; other commands are told the tune runs), and Write gains
//! ([`crate::scope::tune::write`], as `--write`).

use super::super::hub::lock;
use super::{Cmd, Hooks, JobInfo, Machine};
use crate::job::{self, Failure};
use crate::link::{Link, Transport};
use crate::scope::tune;

impl Machine<'_> {
    /// Tune or Write gains from the panel, between jobs.
    pub(super) fn tune_command<T: Transport>(
        &mut self,
        link: &mut Link<T>,
        page: u64,
        cmd: Cmd,
    ) -> Result<Option<String>, Failure> {
        let r = match cmd {
            Cmd::Tune {
                joint,
                amplitude,
                bandwidth,
                phase_margin,
            } => self.tune(link, page, &joint, amplitude, bandwidth, phase_margin),
            _ => self.write_gains(),
        };
        {
            let mut t = lock(&self.hub.tune);
            t.running = None;
            t.error = r.as_ref().err().map(|f| f.message.clone());
        }
        self.hub.publish_tune();
        r.map(Some)
    }

    fn tune<T: Transport>(
        &mut self,
        link: &mut Link<T>,
        page: u64,
        joint: &str,
        amplitude: Option<f64>,
        bandwidth: Option<f64>,
        phase_margin: Option<f64>,
    ) -> Result<String, Failure> {
        let args = super::super::tune::args(joint, amplitude, bandwidth, phase_margin);
        let loaded = tune::load(&args, self.machine_file.as_deref())?;
        {
            let mut t = lock(&self.hub.tune);
            t.running = Some(joint.to_string());
            t.error = None;
        }
        self.hub.publish_tune();
        self.last_job = "tune";
        let mut info = JobInfo::new("tune", page, 0);
        let r = {
            let mut hooks = Hooks {
                m: self,
                info: &mut info,
            };
            tune::tune(link, &args, &loaded, &mut hooks)
        };
        // The tune used the recorder: whatever the scope had armed is off.
        self.scope_off();
        let t = r?;
        let svg = t.svg().map_err(|e| Failure::new(job::exit::BAD_INPUT, e))?;
        let summary = format!(
            "tuned {}: fit {:.1} %, designed kp {:.4e} ki {:.4e} kd {:.4e}",
            t.name, t.fit_percent, t.designed[0], t.designed[1], t.designed[2]
        );
        {
            let mut s = lock(&self.hub.tune);
            s.result = Some((t, svg));
            s.written = None;
        }
        self.hub.log("info", &summary);
        Ok(summary)
    }

    /// The last tune's gains into the machine file's servo line of its joint.
    fn write_gains(&mut self) -> Result<String, Failure> {
        let bad = |m: &str| Failure::new(job::exit::BAD_INPUT, format!("Write gains: {m}"));
        let path = self.machine_file.clone().ok_or_else(|| {
            bad("the station's machine has no file to write into (serve with --machine FILE)")
        })?;
        let tuned = lock(&self.hub.tune)
            .result
            .as_ref()
            .map(|r| r.0.clone())
            .ok_or_else(|| bad("nothing tuned yet: Tune a joint first"))?;
        let line = tune::write(&path, &tuned).map_err(|f| bad(&f.message))?;
        let text = format!(
            "written to {} (joint {}): {line}; the controller runs the new gains once the \
             station loads the file again",
            path.display(),
            tuned.name
        );
        lock(&self.hub.tune).written = Some(text.clone());
        self.hub.log("info", &text);
        Ok(text)
    }
}
