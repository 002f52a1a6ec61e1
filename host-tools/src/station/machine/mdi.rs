//! The station's MDI line: its blocks as a job, then the probing move it ends in, if
//! it does (G38.2–G38.5 line by line, docs/probing.md).

use super::{Hooks, JobInfo, Machine};
use crate::job::{self, Failure};
use crate::link::{JobEnd, Link, Transport};
use pkmc::motion::block::Block;
use serde_json::json;

impl Machine<'_> {
    /// An MDI line's blocks, then the probing move it ends in (if it does).
    pub(super) fn run_mdi<T: Transport>(
        &mut self,
        link: &mut Link<T>,
        line: &job::LineBlocks,
        page: u64,
    ) -> Result<JobEnd, Failure> {
        let n = line.blocks.len() + usize::from(line.probe.is_some());
        let mut info = JobInfo::new("mdi", page, n);
        let mut end = JobEnd::Done;
        if !line.blocks.is_empty() {
            end = self.run(link, &line.blocks, &mut info)?;
        }
        match line.probe {
            Some((block, probing)) if end == JobEnd::Done => {
                self.mdi_probe(link, &block, probing, &mut info)
            }
            _ => Ok(end),
        }
    }

    /// An MDI line's probing move, run as `nc-send` runs one
    /// ([`job::probing::probe`]) once the line's other blocks have run. What it found
    /// goes to every page (`{"type": "probe", "source": "mdi", "probe": …}`, the
    /// shape of the report's [`job::probing::ProbeRecord`]) and to the MDI's front
    /// end (#5061–#5070 for the next lines). A G38.2 or G38.4 without the change is
    /// then refused at its line and column, as in a program.
    fn mdi_probe<T: Transport>(
        &mut self,
        link: &mut Link<T>,
        block: &Block,
        probing: crate::gcode::interp::probe::Probing,
        info: &mut JobInfo,
    ) -> Result<JobEnd, Failure> {
        self.last_job = info.kind;
        let machine = self.machine;
        let mut hooks = Hooks { m: self, info };
        let (found, end) = job::probing::probe(link, machine, block, probing, &mut hooks)?;
        let Some((outcome, record)) = found else {
            return Ok(end);
        };
        self.hub
            .broadcast(&json!({"type": "probe", "source": "mdi", "probe": record}));
        self.mdi.pipeline.probed(&outcome, block.line)?;
        Ok(end)
    }
}
