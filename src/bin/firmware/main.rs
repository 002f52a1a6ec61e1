//! pkmc firmware for the STM32G474RE (NUCLEO-G474RE), and its host-side launcher.
//!
//! One file, two builds. For the MCU (`target_os = "none"`) it is the embassy
//! firmware: a 10 kHz servo interrupt running every servo channel's loop
//! ([`servo_period`]: encoders in, DAC commands and amplifier enable out), which paces
//! a 1 kHz interpolation tick: the tick applies the previous tick's stepper outputs
//! (step trains in timer hardware, DIR, ENABLE), samples the e-stop and limit/home
//! switches, advances a [`Controller`] kept in a static on them (debounced) and on the
//! servo interrupt's snapshot, posts its servo targets to the servo loops, and
//! refreshes the independent watchdog (the pacing and the debouncing are the core's,
//! `pkmc::controller::pacing` and `pkmc::drive::debounce`, shared with the simulator: these handlers only
//! read and write the hardware around them); a USB CDC-ACM link feeding the
//! controller's `receive` and draining its `transmit`; a heartbeat LED. For the host
//! it is a launcher that re-runs cargo for the MCU target, so `cargo run --release` at
//! the repository root builds, flashes and runs the firmware through the probe-rs
//! runner of `.cargo/config.toml`.
//!
//! Invariants: the controller is built once and moved once into its static before the
//! servo timer starts; afterwards it is touched only under the tick's priority-ceiling
//! lock ([`shared`]), by the tick interrupt and by the tasks, never by the servo
//! interrupt. Only `board.rs` and its modules name pins, timers and interrupts. Pin
//! maps (the default wiring, and the eight-servo one of `--features board-servo8`):
//! `docs/wiring.md`.
#![cfg_attr(target_os = "none", no_std, no_main)]

/// Host-side launcher: runs `cargo run --release -p pkmc --bin firmware --target
/// thumbv7em-none-eabihf` from the package directory, followed by this program's own
/// arguments (so `cargo run --release -- -- <probe-rs args>` passes them to the
/// runner), and exits with its status. `-p pkmc` keeps the host tools' `std` features
/// out of the MCU build (the workspace's default members include them).
#[cfg(not(target_os = "none"))]
fn main() {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".to_owned());
    let status = std::process::Command::new(&cargo)
        .args(["run", "--release", "-p", "pkmc", "--bin", "firmware"])
        .args(["--target", "thumbv7em-none-eabihf"])
        .args(std::env::args_os().skip(1))
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .status();
    match status {
        Ok(status) => std::process::exit(status.code().unwrap_or(1)),
        Err(e) => {
            eprintln!("firmware launcher: cannot run {cargo}: {e}");
            std::process::exit(1);
        }
    }
}

#[cfg(target_os = "none")]
mod board;
#[cfg(target_os = "none")]
mod encoders;
#[cfg(target_os = "none")]
mod log;
#[cfg(target_os = "none")]
mod probe;
#[cfg(target_os = "none")]
mod servo_period;
#[cfg(target_os = "none")]
mod shared;
#[cfg(all(target_os = "none", not(feature = "board-servo8")))]
mod steppers;
#[cfg(target_os = "none")]
mod time_driver;

#[cfg(target_os = "none")]
pub use firmware::on_tick;
#[cfg(target_os = "none")]
pub use servo_period::on_servo_period;

/// The MCU side: statics, the tick and the tasks.
#[cfg(target_os = "none")]
mod firmware {
    use defmt::{info, unwrap, warn};
    use embassy_executor::Spawner;
    use embassy_futures::join::join;
    use embassy_futures::select::select;
    use embassy_stm32::gpio::Output;
    use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
    use embassy_sync::signal::Signal;
    use embassy_time::{Duration, Instant, Ticker, Timer};
    use embassy_usb::class::cdc_acm::{self, CdcAcmClass, Sender};
    use embassy_usb::driver::EndpointError;
    use embassy_usb::{Builder, UsbDevice};
    use panic_probe as _;
    use pkmc::controller::pacing::{RawInputs, TickPacer};
    use pkmc::controller::Controller;
    use pkmc::drive::contour::ServoBank;
    use pkmc::drive::debounce::Switches as SwitchStates;
    use pkmc::drive::recorder::ROW_BYTES;
    use pkmc::drive::servo::SERVO_PER_TICK;
    use pkmc::wire::{AlarmCause, State};
    use static_cell::StaticCell;

    use crate::board::{self, StepStats, Steppers, Switches, UsbDriver};
    use crate::shared::TickShared;
    use crate::{log, servo_period};

    /// USB full-speed bulk packet size, bytes.
    const USB_PACKET: usize = 64;
    /// How often the link task drains the controller's transmit buffer when nothing was
    /// received: well inside the controller's 50 ms status period.
    const TX_POLL: Duration = Duration::from_millis(5);
    /// Seconds between two diagnostic log lines of the heartbeat task.
    const LOG_EVERY_S: u32 = 10;

    /// Where the controller lives (in .bss: no 12 KB initial image in flash).
    static CONTROLLER_CELL: StaticCell<Controller> = StaticCell::new();
    /// The controller. `None` only during start-up.
    static CONTROLLER: TickShared<Option<&'static mut Controller>> = TickShared::new(None);
    /// Where the tick's I/O lives (in .bss, like the controller).
    static TICK_IO_CELL: StaticCell<TickIo> = StaticCell::new();
    /// What the tick drives and reads. `None` only during start-up.
    static TICK_IO: TickShared<Option<&'static mut TickIo>> = TickShared::new(None);

    /// The tick's hardware and its side of the pacing.
    struct TickIo {
        /// STEP/DIR/ENABLE outputs.
        steppers: Steppers,
        /// E-stop and limit/home inputs.
        switches: Switches,
        /// Switch filters and the outputs due at the start of the next tick.
        pacer: TickPacer,
        /// The touch probe's input and capture.
        probe: crate::probe::Probe,
        /// Servo periods counted at the last watchdog refresh.
        fed_at: u32,
        /// Ticks run since start-up.
        ticks: u32,
    }

    /// Runs `f` on the controller under the tick's lock.
    fn with_controller<R>(f: impl FnOnce(&mut Controller) -> R) -> Option<R> {
        CONTROLLER.lock(|c| c.as_deref_mut().map(f)).flatten()
    }

    /// One interpolation tick; called by the tick interrupt, which the servo interrupt
    /// pends at every tick edge.
    ///
    /// First applies the stepper outputs computed one tick ago ([`TickPacer::due`]: so
    /// step trains start a short, fixed time after the tick edge), then samples the
    /// switches and runs [`TickPacer::tick`] on them and on the servo interrupt's
    /// snapshot of the edge (debouncing, the controller's tick), and posts the command
    /// it returns (servo targets, with a rebuilt bank when the controller asks for a
    /// servo reset) for the next edge. Last, it refreshes the watchdog if the servo
    /// interrupt has run since the previous refresh: a stalled servo interrupt (which
    /// also stops pending the tick) or a stalled tick both let the watchdog reset the
    /// chip.
    pub fn on_tick() {
        let snapshot = servo_period::snapshot();
        TICK_IO.lock(|io| {
            let Some(io) = io.as_deref_mut() else {
                return;
            };
            io.steppers.apply(io.pacer.due());
            let (probe, probe_edge_us) = io
                .probe
                .read(board::PROBE_ACTIVE == embassy_stm32::gpio::Level::High);
            let limits = io.switches.limits();
            let raw = RawInputs {
                switches: SwitchStates {
                    estop: io.switches.estop(),
                    // Shared home/limit switches: one input per joint, both roles.
                    limit: limits,
                    home: limits,
                },
                probe,
                probe_edge_us,
                // No stepper fault lines and no index inputs on this board (no pin
                // left); the amplifiers' fault line comes with the snapshot.
                ..RawInputs::default()
            };
            let ticked = CONTROLLER
                .lock(|c| {
                    let c = c.as_deref_mut()?;
                    let command = io.pacer.tick(c, &raw, &snapshot);
                    if command.reset {
                        servo_period::restart(ServoBank::new(c.machine(), &snapshot.counts));
                    }
                    servo_period::post(command);
                    if c.records_servo() {
                        // Two short critical sections copy the halves; one call hands
                        // them over (the same tick's unless its signals changed).
                        let mut rows = [[0; ROW_BYTES]; SERVO_PER_TICK];
                        let (a, b) = rows.split_at_mut(SERVO_PER_TICK / 2);
                        let first = servo_period::staged(0);
                        let second = servo_period::staged(1);
                        if let (Some((ids, r0)), Some((again, r1))) = (first, second) {
                            if ids == again {
                                a.copy_from_slice(&r0);
                                b.copy_from_slice(&r1);
                                c.record_servo(&ids, &rows);
                            }
                        }
                    }
                    Some(())
                })
                .flatten()
                .is_some();
            if ticked && snapshot.periods != io.fed_at {
                board::feed_watchdog();
                io.fed_at = snapshot.periods;
            }
            io.ticks = io.ticks.wrapping_add(1);
        });
    }

    /// Bytes of a stored machine record, padded to the flash write size (8 bytes).
    const RECORD_BYTES: usize =
        (pkmc::wire::store::HEADER_BYTES + pkmc::wire::store::MAX_CONFIG_BYTES).div_ceil(8) * 8;

    /// Builds the controller for the machine kept in flash (the wiring's built-in
    /// machine when the page holds none, or one on channels this wiring lacks) and moves
    /// it, once, into its static; it checks every machine loaded later against the
    /// wiring's channels ([`board::CHANNELS`]). After a watchdog reset it starts with
    /// the `Watchdog` alarm.
    fn install_controller(flash: &mut board::BoardFlash, watchdog_reset: bool) {
        let mut record = [0xFFu8; RECORD_BYTES];
        let stored = flash
            .blocking_read(board::CONFIG_PAGE_OFFSET, &mut record)
            .ok()
            .and_then(|_| pkmc::wire::store::read_record(&record).ok());
        let machine = match stored {
            Some(m) => {
                info!("machine from flash: {}", m.name.as_str());
                m
            }
            None => {
                info!("no machine in flash: built-in machine");
                board::builtin_machine()
            }
        };
        // Built in place in its static cell: the controller is larger than the stack
        // could hold as a temporary.
        let slot = CONTROLLER_CELL.uninit();
        // The refusal is not worded here (its text costs 3.3 KiB of flash): the host
        // sees the machine differ from its file and, loading it, gets the reason.
        if Controller::init_on(slot, machine, board::CHANNELS).is_err() {
            warn!("the stored machine does not fit this wiring: built-in machine");
            if Controller::init_on(slot, board::builtin_machine(), board::CHANNELS).is_err() {
                defmt::panic!("the built-in machine configuration is invalid");
            }
        }
        // SAFETY: one of the two `init`s succeeded and wrote every field.
        let controller = unsafe { slot.assume_init_mut() };
        if watchdog_reset {
            controller.raise_at_start(AlarmCause::Watchdog);
        }
        CONTROLLER.lock(|c| c.replace(controller));
    }

    /// Writes a machine the host loaded into the flash page, so the controller comes
    /// back with it after a reset. Runs only when the controller is at rest (it loads
    /// machines only then).
    ///
    /// The pages are in flash bank 2 and the program runs from bank 1, so the erase
    /// (up to 40 ms) and the writes do not stall the servo loops or the tick
    /// (read-while-write in dual-bank mode). The erase and the writes are awaited (the
    /// flash's end-of-operation interrupt wakes the task), so the executor runs the
    /// link task meanwhile: a blocking erase held every other task off for about 44 ms,
    /// seen on the virtual board (docs/vboard.md). The watchdog is refreshed right
    /// before the erase all the same, so that even a stalling erase would have the
    /// whole watchdog timeout ([`board::WATCHDOG_MS`]).
    #[embassy_executor::task]
    async fn store_task(mut flash: board::BoardFlash) {
        let mut record = [0xFFu8; RECORD_BYTES];
        loop {
            Timer::after_millis(100).await;
            let len = with_controller(|c| {
                let m = c.take_store_request()?;
                let mut rec =
                    [0u8; pkmc::wire::store::HEADER_BYTES + pkmc::wire::store::MAX_CONFIG_BYTES];
                let n = pkmc::wire::store::record(m, &mut rec)?;
                record.fill(0xFF);
                record[..n].copy_from_slice(&rec[..n]);
                Some(n)
            })
            .flatten();
            let Some(n) = len else {
                continue;
            };
            let end = board::CONFIG_PAGE_OFFSET + board::CONFIG_PAGE_BYTES;
            let padded = n.div_ceil(8) * 8;
            board::feed_watchdog();
            let mut written = flash.erase(board::CONFIG_PAGE_OFFSET, end).await;
            if written.is_ok() {
                written = flash
                    .write(board::CONFIG_PAGE_OFFSET, &record[..padded])
                    .await;
            }
            match written {
                Ok(()) => info!("machine stored in flash ({} bytes)", n),
                Err(_) => warn!("could not store the machine in flash"),
            }
        }
    }

    /// Start-up: reset cause, clocks, board (the watchdog starts there), controller,
    /// servo loops and tick, tasks.
    #[embassy_executor::main]
    async fn main(spawner: Spawner) {
        let watchdog_reset = board::take_watchdog_reset();
        let p = embassy_stm32::init(board::clock_config());
        info!("pkmc firmware {}", env!("CARGO_PKG_VERSION"));
        if watchdog_reset {
            warn!("reset by the watchdog");
        }
        let mut board = board::init(p);
        install_controller(&mut board.flash, watchdog_reset);
        // The loops start standing at the encoders, disabled; the first tick asks for a
        // servo reset and enables them as the controller says.
        let counts = board.servo.encoders.read();
        let bank = with_controller(|c| ServoBank::new(c.machine(), &counts));
        let Some(bank) = bank else {
            defmt::panic!("no controller");
        };
        servo_period::install(board.servo, bank);
        let tick_io = TICK_IO_CELL.init(TickIo {
            steppers: board.steppers,
            switches: board.switches,
            pacer: TickPacer::new(),
            probe: board.probe,
            fed_at: 0,
            ticks: 0,
        });
        TICK_IO.lock(|io| io.replace(tick_io));
        board::feed_watchdog();
        board.timer.start();
        info!(
            "servo at {} Hz, tick at {} Hz, watchdog {} ms",
            pkmc::drive::servo::SERVO_HZ,
            pkmc::units::TICK_HZ,
            board::WATCHDOG_MS
        );

        let (usb, class) = usb_device(board.usb);
        spawner.spawn(unwrap!(usb_task(usb)));
        spawner.spawn(unwrap!(link_task(class)));
        spawner.spawn(unwrap!(heartbeat_task(board.led)));
        spawner.spawn(unwrap!(store_task(board.flash)));
    }

    /// Builds the USB device with one CDC-ACM function.
    fn usb_device(
        driver: UsbDriver,
    ) -> (
        UsbDevice<'static, UsbDriver>,
        CdcAcmClass<'static, UsbDriver>,
    ) {
        // Sized for this device: its configuration descriptor (one CDC-ACM function)
        // is 75 bytes and its BOS descriptor 5; embassy-usb refuses to build if a
        // buffer is short, and the virtual board's host reads both back.
        static CONFIG_DESCRIPTOR: StaticCell<[u8; 128]> = StaticCell::new();
        static BOS_DESCRIPTOR: StaticCell<[u8; 32]> = StaticCell::new();
        static CONTROL_BUF: StaticCell<[u8; 64]> = StaticCell::new();
        static CDC_STATE: StaticCell<cdc_acm::State> = StaticCell::new();

        let mut config = embassy_usb::Config::new(board::USB_VID, board::USB_PID);
        config.manufacturer = Some(board::USB_MANUFACTURER);
        config.product = Some(board::USB_PRODUCT);
        config.serial_number = Some(board::USB_SERIAL);
        config.max_power = 100;
        config.max_packet_size_0 = 64;

        let mut builder = Builder::new(
            driver,
            config,
            CONFIG_DESCRIPTOR.init([0; 128]),
            BOS_DESCRIPTOR.init([0; 32]),
            &mut [],
            CONTROL_BUF.init([0; 64]),
        );
        let class = CdcAcmClass::new(
            &mut builder,
            CDC_STATE.init(cdc_acm::State::new()),
            USB_PACKET as u16,
        );
        (builder.build(), class)
    }

    /// Runs the USB device stack.
    #[embassy_executor::task]
    async fn usb_task(mut usb: UsbDevice<'static, UsbDriver>) -> ! {
        usb.run().await
    }

    /// The link: bytes from the host go to `Controller::receive`; what
    /// `Controller::transmit` hands back goes to the host after every received packet
    /// and every [`TX_POLL`].
    #[embassy_executor::task]
    async fn link_task(class: CdcAcmClass<'static, UsbDriver>) {
        let (mut tx, mut rx) = class.split();
        let received: Signal<CriticalSectionRawMutex, ()> = Signal::new();
        let receive = async {
            let mut buf = [0u8; USB_PACKET];
            loop {
                rx.wait_connection().await;
                info!("link: USB configured");
                let mut pacer = ReceivePacer::new();
                while let Ok(n) = rx.read_packet(&mut buf).await {
                    with_controller(|c| c.receive(&buf[..n]));
                    received.signal(());
                    pacer.taken().await;
                }
                info!("link: USB gone");
            }
        };
        let transmit = async {
            let mut ticker = Ticker::every(TX_POLL);
            loop {
                tx.wait_connection().await;
                while drain(&mut tx).await.is_ok() {
                    select(ticker.next(), received.wait()).await;
                }
            }
        };
        join(receive, transmit).await;
    }

    /// Packets the link takes from the host in each millisecond before it waits for
    /// the next one: the wiring's [`board::RECEIVE_PACKETS_PER_MS`]. A host filling the
    /// queue at connection sends as fast as USB allows, and without a limit the
    /// firmware read, decoded and pre-planned blocks at 97 % of the CPU for tens of
    /// milliseconds (the virtual board's busiest periods, docs/vboard.md): the
    /// interrupts were never held up, but nothing was left for the other tasks.
    const RECEIVE_PACKETS_PER_MS: u32 = board::RECEIVE_PACKETS_PER_MS;

    /// Keeps the packets taken within [`RECEIVE_PACKETS_PER_MS`].
    struct ReceivePacer {
        window: Instant,
        packets: u32,
    }

    impl ReceivePacer {
        fn new() -> Self {
            Self {
                window: Instant::now(),
                packets: 0,
            }
        }

        /// Counts a packet; waits for the next millisecond once the allowance is
        /// taken.
        async fn taken(&mut self) {
            let period = Duration::from_millis(1);
            if Instant::now() >= self.window + period {
                self.window = Instant::now();
                self.packets = 0;
            }
            self.packets += 1;
            if self.packets >= RECEIVE_PACKETS_PER_MS {
                Timer::at(self.window + period).await;
                self.window = Instant::now();
                self.packets = 0;
            }
        }
    }

    /// Sends everything the controller has to say, in packets; a full last packet is
    /// followed by a zero-length one so the host sees the end of the transfer.
    async fn drain(tx: &mut Sender<'static, UsbDriver>) -> Result<(), EndpointError> {
        let mut buf = [0u8; USB_PACKET];
        let mut last_full = false;
        loop {
            let n = with_controller(|c| c.transmit(&mut buf)).unwrap_or(0);
            if n == 0 {
                break;
            }
            tx.write_packet(&buf[..n]).await?;
            last_full = n == USB_PACKET;
        }
        if last_full {
            tx.write_packet(&[]).await?;
        }
        Ok(())
    }

    /// Blinks LD2 (1 Hz idle, 4 Hz running, 10 Hz in any other state) and logs
    /// diagnostics every [`LOG_EVERY_S`] seconds.
    #[embassy_executor::task]
    async fn heartbeat_task(mut led: Output<'static>) {
        let mut elapsed_ms = 0u32;
        loop {
            let state = with_controller(|c| c.state()).unwrap_or(State::Alarm);
            let half_period_ms: u64 = match state {
                State::Idle => 500,
                State::Running => 125,
                _ => 50,
            };
            led.toggle();
            Timer::after_millis(half_period_ms).await;
            elapsed_ms += half_period_ms as u32;
            if elapsed_ms >= LOG_EVERY_S * 1000 {
                elapsed_ms = 0;
                log_diagnostics(state);
            }
        }
    }

    /// Logs controller, link, servo and step-output counters and the active inputs.
    fn log_diagnostics(state: State) {
        let (stats, ticks, inputs) = TICK_IO
            .lock(|io| {
                io.as_deref()
                    .map(|io| (io.steppers.stats(), io.ticks, io.pacer.switches()))
            })
            .flatten()
            .unwrap_or((StepStats::default(), 0, SwitchStates::default()));
        let link = with_controller(|c| c.link_stats()).unwrap_or_default();
        let servo = servo_period::stats();
        info!(
            "state {} ticks {} link corrupt {} tx_dropped {} steps {} servo periods {} late_ticks {} fault {} log dropped {}",
            state,
            ticks,
            link.corrupt,
            link.tx_dropped,
            stats,
            servo.periods,
            servo.late_ticks,
            servo.fault,
            log::dropped()
        );
        if inputs.estop || inputs.limit != 0 {
            warn!(
                "inputs active: e-stop {} limit/home {=u16:#b}",
                inputs.estop, inputs.limit
            );
        }
    }
}
