//! A program that probes (G38.2–G38.5), run from the page a stage at a time by the
//! loop nc-send runs ([`probing::run_on`]): each stage a job under the station's
//! hooks (hold, resume, stop, override, the heartbeat's watch), each probing move's
//! result published to the pages as it comes (`probes` messages, [`ProbeRun`]), and a
//! refusal (a G38.2 that found nothing, a move out of reach after a probe) at its line.

use super::{lock, not_runnable, Hooks, JobInfo, Machine};
use crate::job::{probing, Failure};
use crate::link::{JobEnd, Link, Transport};
use crate::station::hub::ProbeRun;

/// The loaded program, to run a stage at a time.
pub(in crate::station) struct StagedProgram {
    text: String,
    name: String,
    /// Its blocks as the preview counted them (each probing move one).
    total: usize,
    compress: Option<crate::gcode::compress::Settings>,
}

impl Machine<'_> {
    /// The loaded program, if it can run.
    pub(in crate::station) fn staged_program(&self) -> Result<StagedProgram, Failure> {
        let p = lock(&self.hub.program);
        if !p.runnable() {
            return Err(not_runnable(&p));
        }
        Ok(StagedProgram {
            text: p.text.clone(),
            name: p.name.clone(),
            total: p.blocks().len(),
            compress: p.compress,
        })
    }

    /// Runs `program` from where the machine stands, a stage at a time; the pages see
    /// each probing move's result as it comes and how the run ended.
    pub(in crate::station) fn run_staged<T: Transport>(
        &mut self,
        link: &mut Link<T>,
        page: u64,
        program: StagedProgram,
    ) -> Result<JobEnd, Failure> {
        let start = link.request_status()?.pose;
        *lock(&self.hub.probes) = ProbeRun {
            program: program.name.clone(),
            running: true,
            ..ProbeRun::default()
        };
        self.hub.publish_probes();
        // The hooks borrow the machine thread: the program keeps its own tool table.
        let tools = self.tools.clone();
        let p = probing::ProbingProgram {
            text: &program.text,
            name: &program.name,
            machine: self.machine,
            start,
            tools: &tools,
            compress: program.compress.as_ref(),
        };
        let mut info = JobInfo::new("program", page, program.total);
        self.last_job = info.kind;
        // As a program streams (see `Cmd::Run`): the host's silence starves it and
        // holds it after the host timeout. Each stage is a job of its own, unmarked:
        // `nc-send resume` takes none of them up.
        link.set_program(self.program_timeout, pkmc::wire::JobMark::default());
        let mut hooks = Hooks {
            m: self,
            info: &mut info,
        };
        let r = probing::run_on(link, &p, &mut hooks);
        link.set_program(None, pkmc::wire::JobMark::default());
        let ended = match &r {
            Ok((JobEnd::Done, ..)) => "done",
            Ok((JobEnd::Alarm(_), ..)) => "alarm",
            Ok((JobEnd::Aborted | JobEnd::Stopped, ..)) => "stopped",
            Ok((JobEnd::Paused(_), ..)) => "paused",
            Err(_) if lock(&self.hub.probes).refusal.is_some() => "refused",
            Err(_) => "failed",
        };
        {
            let mut run = lock(&self.hub.probes);
            run.running = false;
            run.end = Some(ended);
        }
        self.hub.publish_probes();
        Ok(r?.0)
    }
}

impl probing::ProbingHooks for Hooks<'_, '_> {
    fn stage(&mut self, blocks: usize) {
        let info = &mut *self.info;
        info.base = info.sent;
        info.sent += blocks;
        info.total = info.total.max(info.sent);
    }

    fn wants_program_frame(&self) -> bool {
        true
    }

    fn probed(&mut self, record: &probing::ProbeRecord, program: Option<[f64; 3]>) {
        let info = &mut *self.info;
        info.sent += 1;
        info.base = info.sent;
        info.total = info.total.max(info.sent);
        let mut run = lock(&self.m.hub.probes);
        run.records.push(record.clone());
        run.program_frame.push(program);
        drop(run);
        self.m.hub.publish_probes();
    }

    fn refused(&mut self, line: usize, col: usize, message: &str) {
        lock(&self.m.hub.probes).refusal = Some((line, col, message.to_string()));
        self.m.hub.publish_probes();
    }
}
