//! pkmc firmware for the STM32G474RE (NUCLEO-G474RE), and its host-side launcher.
//!
//! One file, two builds. For the MCU (`target_os = "none"`) it is the embassy
//! firmware: a [`Controller`] for the built-in machine in a static, advanced by a
//! 1 kHz hardware timer interrupt that applies the previous tick's outputs (step
//! trains in timer hardware, DIR, ENABLE), reads the encoders and computes the next
//! tick; a USB CDC-ACM link feeding the controller's `receive` and draining its
//! `transmit`; a heartbeat LED. For the host it is a launcher that re-runs cargo for
//! the MCU target, so `cargo run --release` at the repository root builds, flashes and
//! runs the firmware through the probe-rs runner of `.cargo/config.toml`.
//!
//! Invariants: the controller is built once and moved once into its static before the
//! tick starts; afterwards it is touched only inside critical sections, by the tick
//! interrupt and by the link task. Only `board.rs` names pins, timers and interrupts.
//! Pin map: `docs/wiring.md`.
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
mod steppers;
#[cfg(target_os = "none")]
mod time_driver;

#[cfg(target_os = "none")]
pub use firmware::on_tick;

/// The MCU side: statics, the tick and the tasks.
#[cfg(target_os = "none")]
mod firmware {
    use core::cell::RefCell;

    use critical_section::{CriticalSection, Mutex};
    use defmt::{info, unwrap, warn};
    use embassy_executor::Spawner;
    use embassy_futures::join::join;
    use embassy_futures::select::select;
    use embassy_stm32::flash::{Blocking, Flash};
    use embassy_stm32::gpio::{Input, Output};
    use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
    use embassy_sync::signal::Signal;
    use embassy_time::{Duration, Ticker, Timer};
    use embassy_usb::class::cdc_acm::{self, CdcAcmClass, Sender};
    use embassy_usb::driver::EndpointError;
    use embassy_usb::{Builder, UsbDevice};
    use pkmc::config::MachineConfig;
    use pkmc::controller::{Controller, Inputs, Outputs};
    use pkmc::protocol::State;
    use static_cell::StaticCell;
    use {defmt_rtt as _, panic_probe as _};

    use crate::board::{self, Panel, UsbDriver};
    use crate::encoders::Encoders;
    use crate::steppers::{StepStats, Steppers};

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
    static CONTROLLER: Mutex<RefCell<Option<&'static mut Controller>>> =
        Mutex::new(RefCell::new(None));
    /// What the tick interrupt drives. `None` only during start-up.
    static TICK_IO: Mutex<RefCell<Option<TickIo>>> = Mutex::new(RefCell::new(None));

    /// The hardware of the tick and the outputs it applies next.
    struct TickIo {
        /// STEP/DIR/ENABLE outputs.
        steppers: Steppers,
        /// Servo encoder counters.
        encoders: Encoders,
        /// E-stop input.
        estop: Input<'static>,
        /// Inputs handed to the controller (fields the firmware does not read keep their
        /// defaults).
        inputs: Inputs,
        /// Outputs computed by the previous tick, applied at the start of the next.
        pending: Outputs,
        /// Ticks run since start-up.
        ticks: u32,
    }

    /// Runs `f` on the controller inside a critical section.
    fn with_controller<R>(f: impl FnOnce(&mut Controller) -> R) -> Option<R> {
        critical_section::with(|cs| CONTROLLER.borrow_ref_mut(cs).as_deref_mut().map(f))
    }

    /// One interpolation tick; called by the tick timer's interrupt handler.
    ///
    /// First applies the outputs computed one tick ago (so step trains start a short,
    /// fixed time after the tick edge), then reads the encoders and advances the
    /// controller. The e-stop input disables the drives and holds back step trains
    /// (the core's `Inputs` has no e-stop field yet, so the controller does not know).
    pub fn on_tick() {
        critical_section::with(|cs| {
            let Ok(mut io) = TICK_IO.borrow(cs).try_borrow_mut() else {
                return;
            };
            let Some(io) = io.as_mut() else {
                return;
            };
            let estop = io.estop.get_level() == board::ESTOP_ACTIVE;
            io.steppers.apply(&io.pending, !estop);
            io.inputs.encoder_counts = io.encoders.read();
            tick_controller(cs, &io.inputs, &mut io.pending);
            io.ticks = io.ticks.wrapping_add(1);
        });
    }

    /// Advances the controller one tick and stores its outputs in `pending`.
    fn tick_controller(cs: CriticalSection, inputs: &Inputs, pending: &mut Outputs) {
        if let Ok(mut controller) = CONTROLLER.borrow(cs).try_borrow_mut() {
            if let Some(controller) = controller.as_deref_mut() {
                *pending = *controller.tick(inputs);
            }
        }
    }

    /// Bytes of a stored machine record, padded to the flash write size (8 bytes).
    const RECORD_BYTES: usize =
        (pkmc::store::HEADER_BYTES + pkmc::store::MAX_CONFIG_BYTES).div_ceil(8) * 8;

    /// Builds the controller for the machine kept in flash (the built-in Cartesian
    /// machine when the page holds none) and moves it, once, into its static.
    fn install_controller(flash: &mut Flash<'static, Blocking>) {
        let mut record = [0xFFu8; RECORD_BYTES];
        let stored = flash
            .blocking_read(board::CONFIG_PAGE_OFFSET, &mut record)
            .ok()
            .and_then(|_| pkmc::store::read_record(&record).ok());
        let machine = match stored {
            Some(m) => {
                info!("machine from flash: {}", m.name.as_str());
                m
            }
            None => {
                info!("no machine in flash: built-in Cartesian machine");
                MachineConfig::cartesian_xyz()
            }
        };
        let controller = match Controller::new(machine) {
            Ok(c) => CONTROLLER_CELL.init(c),
            Err(_) => match Controller::new(MachineConfig::cartesian_xyz()) {
                Ok(c) => CONTROLLER_CELL.init(c),
                Err(_) => defmt::panic!("the built-in machine configuration is invalid"),
            },
        };
        critical_section::with(|cs| CONTROLLER.borrow_ref_mut(cs).replace(controller));
    }

    /// Writes a machine the host loaded into the flash page, so the controller comes
    /// back with it after a reset. Runs only when the controller is at rest (it loads
    /// machines only then); erasing stalls flash reads, and so the tick, for tens of ms.
    #[embassy_executor::task]
    async fn store_task(mut flash: Flash<'static, Blocking>) {
        let mut record = [0xFFu8; RECORD_BYTES];
        loop {
            Timer::after_millis(100).await;
            let len = with_controller(|c| {
                let m = c.take_store_request()?;
                let mut rec = [0u8; pkmc::store::HEADER_BYTES + pkmc::store::MAX_CONFIG_BYTES];
                let n = pkmc::store::record(m, &mut rec)?;
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
            let written = flash
                .blocking_erase(board::CONFIG_PAGE_OFFSET, end)
                .and_then(|_| flash.blocking_write(board::CONFIG_PAGE_OFFSET, &record[..padded]));
            match written {
                Ok(()) => info!("machine stored in flash ({} bytes)", n),
                Err(_) => warn!("could not store the machine in flash"),
            }
        }
    }

    /// Start-up: clocks, board, controller, tick, tasks.
    #[embassy_executor::main]
    async fn main(spawner: Spawner) {
        let p = embassy_stm32::init(board::clock_config());
        info!("pkmc firmware {}", env!("CARGO_PKG_VERSION"));
        let mut board = board::init(p);
        install_controller(&mut board.flash);
        critical_section::with(|cs| {
            TICK_IO.borrow_ref_mut(cs).replace(TickIo {
                steppers: board.steppers,
                encoders: board.encoders,
                estop: board.estop,
                inputs: Inputs::default(),
                pending: Outputs::default(),
                ticks: 0,
            });
        });
        board.tick.start();
        info!("tick running at {} Hz", pkmc::units::TICK_HZ);

        let (usb, class) = usb_device(board.usb);
        spawner.spawn(unwrap!(usb_task(usb)));
        spawner.spawn(unwrap!(link_task(class)));
        spawner.spawn(unwrap!(heartbeat_task(board.led, board.panel)));
        spawner.spawn(unwrap!(store_task(board.flash)));
    }

    /// Builds the USB device with one CDC-ACM function.
    fn usb_device(
        driver: UsbDriver,
    ) -> (
        UsbDevice<'static, UsbDriver>,
        CdcAcmClass<'static, UsbDriver>,
    ) {
        static CONFIG_DESCRIPTOR: StaticCell<[u8; 256]> = StaticCell::new();
        static BOS_DESCRIPTOR: StaticCell<[u8; 256]> = StaticCell::new();
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
            CONFIG_DESCRIPTOR.init([0; 256]),
            BOS_DESCRIPTOR.init([0; 256]),
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
                while let Ok(n) = rx.read_packet(&mut buf).await {
                    with_controller(|c| c.receive(&buf[..n]));
                    received.signal(());
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

    /// Blinks LD2 (1 Hz idle, 4 Hz running, 10 Hz in any other state), holds the
    /// panel's outputs and logs diagnostics and active panel inputs every
    /// [`LOG_EVERY_S`] seconds.
    #[embassy_executor::task]
    async fn heartbeat_task(mut led: Output<'static>, panel: Panel) {
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
                log_diagnostics(state, &panel);
            }
        }
    }

    /// Logs controller, link and step-output counters and any active panel input.
    fn log_diagnostics(state: State, panel: &Panel) {
        let (stats, ticks) = critical_section::with(|cs| {
            TICK_IO
                .borrow_ref(cs)
                .as_ref()
                .map(|io| (io.steppers.stats(), io.ticks))
                .unwrap_or((StepStats::default(), 0))
        });
        let link = with_controller(|c| c.link_stats()).unwrap_or_default();
        info!(
            "state {} ticks {} link corrupt {} tx_dropped {} steps {}",
            state_name(state),
            ticks,
            link.corrupt,
            link.tx_dropped,
            stats
        );
        for (i, limit) in panel.limits.iter().enumerate() {
            if limit.get_level() == board::LIMIT_ACTIVE {
                warn!("limit input {} active", i);
            }
        }
        if panel.servo_fault.get_level() == board::SERVO_FAULT_ACTIVE {
            warn!("servo fault input active");
        }
    }

    /// A short name of `state` for the log (`State` has no defmt formatting).
    fn state_name(state: State) -> &'static str {
        if state == State::Idle {
            "idle"
        } else if state == State::Running {
            "running"
        } else if state == State::Alarm {
            "alarm"
        } else {
            "other"
        }
    }
}
