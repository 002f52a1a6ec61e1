//! Link throughput: `N` short blocks (0.05 mm chords of a 20 mm circle, 6000 mm/min)
//! streamed by the real client ([`pkmc_host::link::Link`]) to the simulated controller
//! over a pseudo-terminal, as fast as flow control allows. The simulator's clock runs
//! free ([`ServeClock::Free`]: as fast as it can while it has motion, not paced to the
//! wall clock as for `nc-send --sim`), so this measures the link and the controller's
//! acceptance (decode, plan, execute), not the machine's speed.
//!
//! Run: `cargo bench -p pkmc-host --bench link` (default 100 000 blocks; give another
//! count as `-- N`). Prints blocks/s until the last block was accepted, blocks/s until
//! the job ended, the simulated motion time and the client's counters.

use pkmc::config::MachineConfig;
use pkmc::motion::block::{Block, Motion};
use pkmc::wire::Control;
use pkmc_host::job::{SimServer, SimSetup};
use pkmc_host::link::{JobEnd, JobHooks, Link, LinkOptions, LinkView, PortTransport};
use pkmc_host::sim::serve::ServeClock;
use std::time::Instant;

/// Records when the last block was acknowledged.
struct Clock {
    all_accepted: Option<Instant>,
}

impl JobHooks for Clock {
    fn control(&mut self, view: &LinkView) -> Option<Control> {
        if self.all_accepted.is_none() && view.acked == view.total {
            self.all_accepted = Some(Instant::now());
        }
        None
    }
}

/// `n` chords of 0.05 mm around a circle of 20 mm radius centred at (60, 60) mm.
fn chords(n: usize, z_nm: i64) -> Vec<Block> {
    let r = 20.0;
    let step = 0.05 / r; // radians per chord
    (0..n)
        .map(|i| {
            let a = (i + 1) as f64 * step;
            let x = 60.0 + r * a.cos();
            let y = 60.0 + r * a.sin();
            Block {
                line: (i + 2) as u32,
                motion: Motion::Linear,
                target: [
                    (x * 1e6).round() as i64,
                    (y * 1e6).round() as i64,
                    z_nm,
                    0,
                    0,
                    0,
                ],
                feed: 100_000_000, // 100 mm/s
                tolerance_nm: u32::MAX,
            }
        })
        .collect()
}

fn main() {
    let n: usize = std::env::args()
        .skip(1)
        .find_map(|a| a.parse().ok())
        .unwrap_or(100_000);
    let machine = pkmc_host::machine_file::parse(
        pkmc_host::machine_file::DEFAULT_MACHINE,
        "built-in machine",
    )
    .expect("the built-in machine parses");
    let home = machine.home;
    let mut blocks = vec![Block {
        line: 1,
        motion: Motion::Rapid,
        target: [80_000_000, 60_000_000, home[2], 0, 0, 0],
        feed: 0,
        tolerance_nm: 0,
    }];
    blocks.extend(chords(n, home[2]));
    run(&machine, &blocks, n);
}

fn run(machine: &MachineConfig, blocks: &[Block], n: usize) {
    // The free clock: this measures the link, not the machine's real time.
    let setup = SimSetup {
        clock: ServeClock::Free,
        ..SimSetup::default()
    };
    let server = SimServer::start(machine.clone(), &setup).expect("simulator");
    let port = PortTransport::open(&server.port_path).expect("pty opens");
    let mut link = Link::connect(port, machine, LinkOptions::default()).expect("handshake");
    let mut clock = Clock { all_accepted: None };
    // A fresh controller is locked after its reset: unlock it where it stands.
    pkmc_host::job::prepare(&mut link, false, true, &mut clock).expect("unlocked");
    let t0 = Instant::now();
    let end = link.run_job(blocks, &mut clock).expect("the job runs");
    let t_end = t0.elapsed();
    let t_acc = clock.all_accepted.map_or(t_end, |t| t - t0);
    let status = link.request_status().expect("status");
    let stats = link.stats;
    drop(link);
    let outcome = server.finish().expect("simulator ends");
    assert_eq!(end, JobEnd::Done, "the job completes");
    assert_eq!(status.blocks_done as usize, blocks.len(), "every block ran");
    assert_eq!(outcome.violation_count, 0, "no drive timing breach");
    println!(
        "link: {n} blocks of 0.05 mm over a pty: {:.0} blocks/s accepted ({:.3} s), \
         {:.0} blocks/s to the end of motion ({:.3} s); simulated motion {:.3} s \
         ({:.0} ticks/s); frames sent {}, resent {}, naks {}, status requests {}",
        blocks.len() as f64 / t_acc.as_secs_f64(),
        t_acc.as_secs_f64(),
        blocks.len() as f64 / t_end.as_secs_f64(),
        t_end.as_secs_f64(),
        status.motion_ticks as f64 * 1e-3,
        outcome.ticks as f64 / t_end.as_secs_f64(),
        stats.frames_sent,
        stats.resent,
        stats.naks,
        stats.status_requests
    );
}
