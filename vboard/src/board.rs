//! The board: the chip's peripherals on their bus addresses, virtual time and its
//! events, and the machine wired to the pins (the simulator's drive and plant models).

use crate::nvic::Scs;
use crate::periph::clocks::{pwr, Rcc, ResetCause};
use crate::periph::dac::Dac;
use crate::periph::flash::{self, Flash};
use crate::periph::gpio::Gpio;
use crate::periph::hrtim::Hrtim;
use crate::periph::iwdg::Iwdg;
use crate::periph::lptim::Lptim;
use crate::periph::plain::{self, Plain};
use crate::periph::timer::{Kind, Pulse, Timer};
use crate::periph::usb::{UsbDevice, IRQ_USB_LP};
use crate::periph::Unmodelled;
use crate::time::to_ns;
use crate::wiring::{CommandSource, EncoderSink, Pin, StepSource, Wiring};
use pkmc::config::{Drive, MachineConfig, MAX_SERVOS, MAX_STEPPERS};
use pkmc_host::sim::{drive_steps, SimServo, SimStepper};

/// The timers by name, base address, kind and NVIC line of their update interrupt.
const TIMERS: &[(&str, u32, Kind, Option<usize>)] = &[
    ("TIM2", 0x4000_0000, Kind::General { wide: true }, Some(28)),
    ("TIM3", 0x4000_0400, Kind::General { wide: false }, Some(29)),
    ("TIM4", 0x4000_0800, Kind::General { wide: false }, Some(30)),
    ("TIM5", 0x4000_0C00, Kind::General { wide: true }, Some(50)),
    ("TIM6", 0x4000_1000, Kind::Basic, Some(54)),
    ("TIM7", 0x4000_1400, Kind::Basic, Some(55)),
    ("TIM1", 0x4001_2C00, Kind::Advanced, Some(25)),
    ("TIM8", 0x4001_3400, Kind::Advanced, Some(44)),
    (
        "TIM15",
        0x4001_4000,
        Kind::Compact { channels: 2 },
        Some(24),
    ),
    (
        "TIM16",
        0x4001_4400,
        Kind::Compact { channels: 1 },
        Some(25),
    ),
    (
        "TIM17",
        0x4001_4800,
        Kind::Compact { channels: 1 },
        Some(26),
    ),
    ("TIM20", 0x4001_5000, Kind::Advanced, Some(78)),
];

/// The NVIC line of the flash interface's interrupt.
const IRQ_FLASH: usize = 4;

/// The servo-period timer whose update events step the plants.
const PLANT_CLOCK: &str = "TIM7";

/// An access without a model, or another reason the run stopped.
#[derive(Clone, Debug)]
pub struct Fault {
    /// What happened.
    pub what: String,
    /// Program counter (start of the block), if known.
    pub pc: Option<u32>,
}

/// The machine behind the pins.
pub struct MachineSide {
    /// The machine file's configuration.
    pub machine: MachineConfig,
    /// Stepper drives by channel.
    pub steppers: [Option<SimStepper>; MAX_STEPPERS],
    /// Servo joints by channel.
    pub servos: [Option<SimServo>; MAX_SERVOS],
    /// Encoder phase (0–3) of each servo channel's quadrature output.
    phase: [i64; MAX_SERVOS],
    /// Steps sent to a drive while its ENABLE was off.
    pub steps_disabled: u64,
    /// Pulses on a STEP pin not in its alternate function.
    pub pulses_lost: u64,
    /// Forced inputs: e-stop, limit bits, amplifier fault per group.
    pub estop: bool,
    /// Limit/home inputs forced open.
    pub limits: u16,
    /// Amplifier fault forced per group.
    pub amp_fault: Vec<bool>,
    /// The touch probe touches (its pin high: `docs/wiring.md`, PROBE).
    pub probe: bool,
    /// Probe changes to come: (time, touching).
    pub probe_plan: Vec<(u64, bool)>,
    /// Probe changes made.
    pub probe_edges: Vec<ProbeEdge>,
}

/// A change of the touch probe at the pin.
#[derive(Clone, Debug)]
pub struct ProbeEdge {
    /// When, units.
    pub at: u64,
    /// Touching after it.
    pub touching: bool,
    /// Time since the servo timer's update event of the last tick edge, units.
    pub in_tick: u64,
    /// Every joint's drive then, as [`MachineSide::joint_steps`].
    pub steps: Vec<i64>,
}

/// Counters of the run.
#[derive(Clone, Debug)]
pub struct Stats {
    /// Busy fraction of each whole 1 ms period, per mille, and whether the host was
    /// streaming blocks in it.
    pub busy: Vec<(u16, bool)>,
    /// Idle time in the current period so far, units.
    pub idle_in_period: u64,
    /// The busiest periods while the host streamed: (per mille, period index = ms
    /// since power-on, code running at its end).
    pub worst_busy: Vec<(u16, u64, u32)>,
    /// The worst servo-interrupt latencies: (latency, code running when it became due).
    pub worst_servo: Vec<(u64, u32)>,
    /// Lowest SP seen at a block start, and the call chain then, unwound from the
    /// ELF's call-frame information (the block first; empty without `.debug_frame`).
    pub min_sp: Option<(u32, Vec<crate::unwind::Frame>)>,
    /// Exceptions taken, by exception number.
    pub taken: std::collections::BTreeMap<u32, u64>,
    /// Start latency of each servo interrupt (time units from the update event).
    pub servo_latency: Vec<u64>,
    /// Watchdog resets.
    pub watchdog_resets: u64,
    /// Software resets.
    pub software_resets: u64,
    /// Resets through the NRST pin.
    pub pin_resets: u64,
    /// The lowest and highest PWM command code seen (HRTIM command channels).
    pub pwm_range: (u16, u16),
    /// Changes of the heartbeat LED's output.
    pub led_toggles: u64,
    /// Deferred FP saves carried out (a floating-point instruction under LSPACT).
    pub lazy_saves: u64,
    /// Extended frames returned from with the save still deferred (never written).
    pub lazy_skipped: u64,
}

impl Default for Stats {
    fn default() -> Self {
        Self {
            busy: Vec::new(),
            idle_in_period: 0,
            worst_busy: Vec::new(),
            worst_servo: Vec::new(),
            min_sp: None,
            taken: Default::default(),
            servo_latency: Vec::new(),
            watchdog_resets: 0,
            software_resets: 0,
            pin_resets: 0,
            pwm_range: (u16::MAX, 0),
            led_toggles: 0,
            lazy_saves: 0,
            lazy_skipped: 0,
        }
    }
}

/// The chip and its machine.
pub struct Board {
    /// Virtual time, units.
    pub now: u64,
    /// Units per instruction at the current SYSCLK.
    pub cycle_units: u64,
    /// Instructions executed.
    pub instructions: u64,
    /// The run must stop at this time (next event).
    pub deadline: u64,
    /// Stop at the next block (something changed).
    pub stop: bool,
    /// Why the run cannot go on.
    pub fault: Option<Fault>,
    /// The system control space.
    pub scs: Scs,
    /// RCC.
    pub rcc: Rcc,
    pwr: Plain,
    /// FLASH interface and configuration pages.
    pub flash: Flash,
    gpio: Vec<Gpio>,
    exti: Plain,
    syscfg: Plain,
    dbgmcu: Plain,
    crs: Plain,
    opamp: Plain,
    comp: Plain,
    /// IWDG.
    pub iwdg: Iwdg,
    /// Timers in [`TIMERS`] order.
    pub tims: Vec<Timer>,
    /// HRTIM1.
    pub hrtim: Hrtim,
    lptim: Lptim,
    /// DAC1–DAC4.
    pub dacs: Vec<Dac>,
    /// USB.
    pub usb: UsbDevice,
    /// The wiring.
    pub wiring: Wiring,
    /// The machine.
    pub machine: MachineSide,
    /// Each comparator's output.
    comp_out: [bool; 7],
    /// Counters.
    pub stats: Stats,
    /// The last reset's cause.
    pub reset_cause: ResetCause,
    /// A reset is due (watchdog or software): the run loop restarts the core.
    pub reset_due: Option<ResetCause>,
    /// The core reached a WFE/WFI at this address with nothing to do.
    pub sleep_request: Option<u32>,
    /// Start address of the block being executed.
    pub block_pc: u32,
    /// The instruction of the last peripheral access.
    pub access_pc: u32,
    /// A deferred FP save carried out at the start of the current block for a
    /// floating-point instruction further in it: (block start, that instruction).
    /// An FPCCR read between the two still sees LSPACT set, as on the core.
    pub lazy_window: Option<(u32, u32)>,
    /// The code running when each exception became pending.
    pub pended_in: Vec<u32>,
    /// The host streamed blocks recently (set by the run loop, for the busy figures).
    pub streaming: bool,
    /// The lowest stack pointer seen at a block's start.
    pub lowest_sp: u32,
    /// An enabled exception is pending but masked: blocks check the masks.
    pub masked_pending: bool,
    /// Instructions per block start executed in the current 1 ms period
    /// (VBOARD_PROFILE set), and those of the busiest period while streaming.
    pub profile: Option<(u64, u64, std::collections::HashMap<u32, u64>)>,
    /// When tracing: the drive positions the servo interrupt of each tick edge reads
    /// (the simulator's trace rows hold what its edge period reads), with the time that
    /// interrupt pends the tick.
    pub trace_rows: Option<Vec<(u64, Vec<i64>)>>,
    /// See `profile`: (busy per mille, period, histogram).
    pub worst_profile: Option<(u16, u64, std::collections::HashMap<u32, u64>)>,
    /// The servo timer's update event of the last tick edge (the tick pended in its
    /// interrupt), units.
    pub tick_edge: u64,
}

impl MachineSide {
    /// The drives of `machine`, standing at the joints `at` (axis units), with
    /// `plants` per joint.
    pub fn new(
        machine: MachineConfig,
        at: &[i64],
        plants: &[Option<pkmc_host::control::plant::PlantFile>],
        groups: usize,
    ) -> anyhow::Result<Self> {
        let mut steppers: [Option<SimStepper>; MAX_STEPPERS] = Default::default();
        let mut servos: [Option<SimServo>; MAX_SERVOS] = Default::default();
        for (j, jc) in machine.joints.iter().enumerate() {
            let truth = at.get(j).copied().unwrap_or(0);
            match jc.drive {
                Drive::Stepper {
                    channel,
                    timing,
                    invert_dir,
                } => {
                    // DIR is low until the firmware drives it (the pin's reset state).
                    let mut d = SimStepper::new(channel as usize, timing, false);
                    d.position = jc.scale.steps_at(truth) * if invert_dir { -1 } else { 1 };
                    steppers[channel as usize] = Some(d);
                }
                Drive::Servo { channel } => {
                    let plant = plants.get(j).and_then(Option::as_ref);
                    servos[channel as usize] = Some(
                        SimServo::new(jc, plant, truth, 0)
                            .map_err(|e| anyhow::anyhow!("joint {j}'s plant: {e}"))?,
                    );
                }
            }
        }
        Ok(Self {
            machine,
            steppers,
            servos,
            phase: [0; MAX_SERVOS],
            steps_disabled: 0,
            pulses_lost: 0,
            estop: false,
            limits: 0,
            amp_fault: vec![false; groups],
            probe: false,
            probe_plan: Vec::new(),
            probe_edges: Vec::new(),
        })
    }

    /// Final position of each joint's drive: steps (stepper) or encoder counts
    /// (servo), from the joint's zero, as the simulator reports them.
    pub fn joint_steps(&self) -> Vec<i64> {
        self.machine
            .joints
            .iter()
            .map(|jc| drive_steps(jc.drive, &self.steppers, &self.servos).unwrap_or(0))
            .collect()
    }

    /// Timing breaches of every stepper drive.
    pub fn violations(&self) -> u64 {
        self.steppers
            .iter()
            .flatten()
            .map(|d| d.violation_count)
            .sum()
    }
}

impl Board {
    /// A board at power-on with `wiring`, `machine` and the configuration pages
    /// `config`.
    pub fn new(wiring: Wiring, machine: MachineSide, config: Vec<u8>) -> Self {
        let mut b = Self {
            now: 0,
            cycle_units: 170,
            instructions: 0,
            deadline: 0,
            stop: false,
            fault: None,
            scs: Scs::default(),
            rcc: Rcc::new(ResetCause::PowerOn, 0),
            pwr: pwr(),
            flash: Flash::new(config),
            gpio: ('A'..='G').map(Gpio::new).collect(),
            exti: plain::exti(),
            syscfg: plain::syscfg(),
            dbgmcu: plain::dbgmcu(),
            crs: plain::crs(),
            opamp: plain::opamp(),
            comp: plain::comp(),
            iwdg: Iwdg::default(),
            tims: Vec::new(),
            hrtim: Hrtim::new(16),
            lptim: Lptim::default(),
            dacs: ["DAC1", "DAC2", "DAC3", "DAC4"]
                .into_iter()
                .map(Dac::new)
                .collect(),
            usb: UsbDevice::default(),
            wiring,
            machine,
            comp_out: [false; 7],
            stats: Stats::default(),
            reset_cause: ResetCause::PowerOn,
            reset_due: None,
            sleep_request: None,
            block_pc: 0,
            access_pc: 0,
            lazy_window: None,
            pended_in: vec![0; 16 + crate::nvic::IRQ_LINES],
            streaming: false,
            lowest_sp: u32::MAX,
            masked_pending: false,
            profile: std::env::var_os("VBOARD_PROFILE").map(|_| (0, u64::MAX, Default::default())),
            worst_profile: None,
            tick_edge: 0,
            trace_rows: None,
        };
        b.reset_peripherals(ResetCause::PowerOn);
        b
    }

    /// Resets the chip's peripherals (the machine, flash contents and time go on).
    pub fn reset_peripherals(&mut self, cause: ResetCause) {
        let csr = self.rcc.csr();
        self.rcc = Rcc::new(cause, csr);
        self.cycle_units = self.rcc.cycle_units().unwrap_or(170);
        self.scs = Scs::default();
        self.pwr.reset();
        let config = std::mem::take(&mut self.flash.config);
        let (erases, programs) = (self.flash.erases, self.flash.programs);
        self.flash = Flash::new(config);
        self.flash.erases = erases;
        self.flash.programs = programs;
        // Pins float back to inputs: the drives see DIR and STEP as the pulls leave
        // them; the board's inputs stay driven.
        let gpio: Vec<Gpio> = ('A'..='G').map(Gpio::new).collect();
        self.gpio = gpio;
        for p in [
            &mut self.exti,
            &mut self.syscfg,
            &mut self.dbgmcu,
            &mut self.crs,
        ] {
            p.reset();
        }
        self.opamp.reset();
        self.comp.reset();
        self.iwdg = Iwdg::default();
        self.tims = TIMERS
            .iter()
            .map(|&(name, _, kind, _)| Timer::new(name, kind, 16))
            .collect();
        self.hrtim = Hrtim::new(16);
        self.hrtim.edges = self
            .wiring
            .steppers
            .iter()
            .any(|s| matches!(s.0, StepSource::Hrtim(..)));
        self.lptim = Lptim::default();
        self.dacs = ["DAC1", "DAC2", "DAC3", "DAC4"]
            .into_iter()
            .map(Dac::new)
            .collect();
        let pma = self.usb.pma;
        self.usb = UsbDevice::default();
        self.usb.pma = pma;
        self.reset_cause = cause;
        self.drive_inputs();
    }

    fn timer_index(&self, name: &str) -> Option<usize> {
        TIMERS.iter().position(|t| t.0 == name)
    }

    /// The peripheral at `addr`, for messages.
    fn name_of(&self, addr: u32) -> String {
        if let Some(i) = TIMERS
            .iter()
            .position(|t| (t.1..t.1 + 0x400).contains(&addr))
        {
            return self.tims[i].name.to_string();
        }
        match addr {
            0x4000_2000..=0x4000_23FF => self.crs.name.into(),
            0x4000_3000..=0x4000_33FF => "IWDG".into(),
            0x4000_5C00..=0x4000_63FF => "USB".into(),
            0x4000_7000..=0x4000_73FF => self.pwr.name.into(),
            0x4000_7C00..=0x4000_7FFF => "LPTIM1".into(),
            0x4001_0000..=0x4001_002F => self.syscfg.name.into(),
            0x4001_0200..=0x4001_02FF => self.comp.name.into(),
            0x4001_0300..=0x4001_03FF => self.opamp.name.into(),
            0x4001_0400..=0x4001_07FF => self.exti.name.into(),
            0x4001_6800..=0x4001_77FF => "HRTIM1".into(),
            0x4002_1000..=0x4002_13FF => "RCC".into(),
            0x4002_2000..=0x4002_23FF => "FLASH".into(),
            0x4800_0000..=0x4800_1BFF => {
                format!(
                    "GPIO{}",
                    self.gpio[((addr - 0x4800_0000) / 0x400) as usize].port
                )
            }
            0x5000_0800..=0x5000_17FF => self.dacs[((addr - 0x5000_0800) / 0x400) as usize]
                .name
                .into(),
            0xE004_2000..=0xE004_23FF => self.dbgmcu.name.into(),
            0xE000_0000..=0xE00F_FFFF => "the Cortex-M4 system space".into(),
            _ => "no peripheral of this model".into(),
        }
    }

    fn unmodelled(&mut self, what: String) {
        if self.fault.is_none() {
            self.fault = Some(Fault {
                what,
                pc: Some(self.access_pc),
            });
        }
        self.stop = true;
    }

    /// A read of `size` bytes at `addr` from the core.
    pub fn read(&mut self, addr: u32, size: usize) -> u32 {
        let aligned = addr & !3;
        let shift = 8 * (addr & 3);
        let r = if (0x4000_6000..0x4000_6400).contains(&addr) {
            self.usb
                .pma_read((addr - 0x4000_6000) as usize, size)
                .ok_or(Unmodelled)
        } else if (0xE000_0000..0xE010_0000).contains(&addr)
            && !(0xE004_2000..0xE004_2400).contains(&addr)
        {
            let early = matches!(self.lazy_window,
                Some((start, fp)) if start == self.block_pc && self.access_pc < fp);
            self.scs
                .read(aligned - 0xE000_0000, self.instructions)
                .map_err(|_| Unmodelled)
                .map(|w| {
                    if early && aligned == 0xE000_EF34 {
                        w | 1
                    } else {
                        w
                    }
                })
                .map(|w| w >> shift)
        } else if (flash::CONFIG..flash::CONFIG + flash::CONFIG_SIZE).contains(&addr) {
            Ok(self.flash.read_memory(addr, size))
        } else {
            self.read_word(aligned).map(|w| w >> shift)
        };
        match r {
            Ok(v) => {
                if size == 4 {
                    v
                } else {
                    v & ((1u32 << (8 * size)) - 1)
                }
            }
            Err(Unmodelled) => {
                let name = self.name_of(addr);
                self.unmodelled(format!(
                    "read of {size} bytes at {addr:#010x} ({name}): not modelled"
                ));
                0
            }
        }
    }

    fn read_word(&mut self, addr: u32) -> Result<u32, Unmodelled> {
        let now = self.now;
        if let Some(i) = TIMERS
            .iter()
            .position(|t| (t.1..t.1 + 0x400).contains(&addr))
        {
            return self.tims[i].read(addr - TIMERS[i].1, now);
        }
        match addr {
            0x4000_2000..=0x4000_23FF => self.crs.read(addr - 0x4000_2000),
            0x4000_3000..=0x4000_33FF => self.iwdg.read(addr - 0x4000_3000, now),
            0x4000_5C00..=0x4000_5FFF => self.usb.read(addr - 0x4000_5C00),
            0x4000_7000..=0x4000_73FF => self.pwr.read(addr - 0x4000_7000),
            0x4000_7C00..=0x4000_7FFF => self.lptim.read(addr - 0x4000_7C00),
            0x4001_0000..=0x4001_002F => self.syscfg.read(addr - 0x4001_0000),
            0x4001_0200..=0x4001_02FF => {
                // VALUE (bit 30): the comparator's output.
                let o = addr - 0x4001_0200;
                let out = self
                    .comp_out
                    .get((o / 4) as usize)
                    .copied()
                    .unwrap_or(false);
                self.comp
                    .read(o)
                    .map(|v| v & !(1 << 30) | u32::from(out) << 30)
            }
            0x4001_0300..=0x4001_03FF => self.opamp.read(addr - 0x4001_0300),
            0x4001_0400..=0x4001_07FF => self.exti.read(addr - 0x4001_0400),
            0x4001_6800..=0x4001_77FF => self.hrtim.read(addr - 0x4001_6800, now),
            0x4002_1000..=0x4002_13FF => self.rcc.read(addr - 0x4002_1000),
            0x4002_2000..=0x4002_23FF => self.flash.read(addr - 0x4002_2000, now),
            0x4800_0000..=0x4800_1BFF => {
                let port = ((addr - 0x4800_0000) / 0x400) as usize;
                self.gpio[port].read(addr & 0x3FF)
            }
            0x5000_0800..=0x5000_17FF => {
                let d = ((addr - 0x5000_0800) / 0x400) as usize;
                self.dacs[d].read(addr & 0x3FF, now)
            }
            0xE004_2000..=0xE004_23FF => self.dbgmcu.read(addr - 0xE004_2000),
            _ => Err(Unmodelled),
        }
    }

    /// A write of `size` bytes of `value` at `addr` from the core.
    pub fn write(&mut self, addr: u32, size: usize, value: u32) {
        let now = self.now;
        let r = if (0x4000_6000..0x4000_6400).contains(&addr) {
            self.usb
                .pma_write((addr - 0x4000_6000) as usize, size, value)
                .ok_or(Unmodelled)
        } else if (0xE000_0000..0xE010_0000).contains(&addr)
            && !(0xE004_2000..0xE004_2400).contains(&addr)
        {
            self.scs.changed = true;
            self.scs
                .write(addr - 0xE000_0000, size as u32, value, now)
                .map_err(|_| Unmodelled)
        } else if (flash::CONFIG..flash::CONFIG + flash::CONFIG_SIZE).contains(&addr) {
            self.flash.write_memory(addr, size, value, now);
            Ok(())
        } else if addr & 3 != 0 {
            Err(Unmodelled)
        } else {
            // A half-word write to a word register (the timers allow it, RM0440
            // "TIMx register map": 16-bit access) sets its low bits, the rest 0.
            self.write_word(addr, value)
        };
        if r.is_err() {
            let name = self.name_of(addr);
            self.unmodelled(format!(
                "write of {size} bytes of {value:#x} at {addr:#010x} ({name}): not modelled"
            ));
        }
        // The tick (UCPD1's line, pended by the servo interrupt) marks a trace row and
        // the tick edge: the update event whose interrupt this is.
        if addr & !3 == 0xE000_E200 + 4 && value & (1 << (63 - 32)) != 0 {
            if let Some(i) = self.timer_index(PLANT_CLOCK) {
                self.tick_edge = self.tims[i].irq_at;
            }
            let row = self.machine.joint_steps();
            if let Some(rows) = self.trace_rows.as_mut() {
                rows.push((now, row));
            }
        }
        if self.scs.changed || self.usb.irq() || self.usb.armed || self.flash.irq() {
            self.stop = true;
        }
    }

    fn write_word(&mut self, addr: u32, value: u32) -> Result<(), Unmodelled> {
        let now = self.now;
        if let Some(i) = TIMERS
            .iter()
            .position(|t| (t.1..t.1 + 0x400).contains(&addr))
        {
            self.tims[i].write(addr - TIMERS[i].1, value, now)?;
            self.collect_pulses();
            self.stop = true; // a timer may now have an earlier event
            return Ok(());
        }
        match addr {
            0x4000_2000..=0x4000_23FF => self.crs.write(addr - 0x4000_2000, value),
            0x4000_3000..=0x4000_33FF => {
                self.iwdg.write(addr - 0x4000_3000, value, now)?;
                self.stop = true;
                Ok(())
            }
            0x4000_5C00..=0x4000_5FFF => self.usb.write(addr - 0x4000_5C00, value),
            0x4000_7000..=0x4000_73FF => self.pwr.write(addr - 0x4000_7000, value),
            0x4000_7C00..=0x4000_7FFF => self.lptim.write(addr - 0x4000_7C00, value),
            0x4001_0000..=0x4001_002F => self.syscfg.write(addr - 0x4001_0000, value),
            0x4001_0200..=0x4001_02FF => self.comp.write(addr - 0x4001_0200, value),
            0x4001_0300..=0x4001_03FF => self.opamp.write(addr - 0x4001_0300, value),
            0x4001_0400..=0x4001_07FF => self.exti.write(addr - 0x4001_0400, value),
            0x4001_6800..=0x4001_77FF => {
                self.hrtim.write(addr - 0x4001_6800, value, now)?;
                self.collect_pulses();
                Ok(())
            }
            0x4002_1000..=0x4002_13FF => {
                self.rcc.write(addr - 0x4002_1000, value)?;
                match self.rcc.cycle_units() {
                    Some(u) => {
                        self.cycle_units = u;
                        Ok(())
                    }
                    None => Err(Unmodelled),
                }
            }
            0x4002_2000..=0x4002_23FF => {
                self.flash.write(addr - 0x4002_2000, value, now)?;
                self.stop = true;
                Ok(())
            }
            0x4800_0000..=0x4800_1BFF => {
                let port = ((addr - 0x4800_0000) / 0x400) as usize;
                // Trains first: a DIR change lands after every edge before it.
                self.advance_outputs();
                let changed = self.gpio[port].write(addr & 0x3FF, value)?;
                if changed != 0 {
                    self.outputs_changed(port, changed);
                }
                Ok(())
            }
            0x5000_0800..=0x5000_17FF => {
                let d = ((addr - 0x5000_0800) / 0x400) as usize;
                self.dacs[d].write(addr & 0x3FF, value, now)
            }
            0xE004_2000..=0xE004_23FF => self.dbgmcu.write(addr - 0xE004_2000, value),
            _ => Err(Unmodelled),
        }
    }

    /// Runs every STEP timer up to now and hands their pulses to the drives.
    pub fn advance_outputs(&mut self) {
        let now = self.now;
        for t in &mut self.tims {
            t.advance(now);
        }
        self.hrtim.advance(now);
        self.collect_pulses();
    }

    fn collect_pulses(&mut self) {
        for s in 0..self.wiring.steppers.len() {
            let (source, _) = self.wiring.steppers[s];
            let (pulses, pin, af): (Vec<Pulse>, Pin, u32) = match source {
                StepSource::Timer(name, ch, pin, af) => {
                    let Some(i) = self.timer_index(name) else {
                        continue;
                    };
                    let t = &mut self.tims[i];
                    let (mine, rest): (Vec<Pulse>, Vec<Pulse>) =
                        t.pulses.drain(..).partition(|p| p.channel == ch);
                    t.pulses = rest;
                    (mine, pin, af)
                }
                StepSource::Hrtim(pin, af) => (std::mem::take(&mut self.hrtim.pulses), pin, af),
            };
            if pulses.is_empty() {
                continue;
            }
            let g = &self.gpio[pin.port];
            let routed = g.mode(pin.pin) == 2 && g.af(pin.pin) == af;
            let enabled = self.step_enabled();
            for p in pulses {
                if !routed {
                    self.machine.pulses_lost += 1;
                    continue;
                }
                if !enabled {
                    self.machine.steps_disabled += 1;
                    continue;
                }
                if let Some(d) = self.machine.steppers[s].as_mut() {
                    d.pulse(to_ns(p.rise), to_ns(p.fall - p.rise));
                }
            }
        }
    }

    fn step_enabled(&self) -> bool {
        self.wiring
            .step_enable
            .is_none_or(|p| self.gpio[p.port].output(p.pin) == Some(true))
    }

    fn outputs_changed(&mut self, port: usize, changed: u32) {
        let t = to_ns(self.now);
        if let Some(led) = self.wiring.led {
            if led.port == port && changed & (1 << led.pin) != 0 {
                self.stats.led_toggles += 1;
            }
        }
        for s in 0..self.wiring.steppers.len() {
            let dir = self.wiring.steppers[s].1;
            if dir.port == port && changed & (1 << dir.pin) != 0 {
                if let (Some(d), Some(level)) = (
                    self.machine.steppers[s].as_mut(),
                    self.gpio[port].output(dir.pin),
                ) {
                    d.dir(t, level);
                }
            }
        }
    }

    /// Drives the board's inputs from the machine's state: e-stop, limits, amplifier
    /// faults (released unless forced).
    pub fn drive_inputs(&mut self) {
        let estop = self.wiring.estop;
        self.gpio[estop.port].drive(estop.pin, Some(self.machine.estop));
        for (k, pin) in self.wiring.limits.clone().into_iter().enumerate() {
            let open = self.machine.limits & (1 << k) != 0;
            self.gpio[pin.port].drive(pin.pin, Some(open));
        }
        for (g, (_, fault)) in self.wiring.amp_lines.clone().into_iter().enumerate() {
            let f = self.machine.amp_fault.get(g).copied().unwrap_or(false);
            self.gpio[fault.port].drive(fault.pin, Some(!f));
        }
        self.drive_probe(self.machine.probe, self.now);
    }

    /// The probe's pin at `touching` (high) from time `t`, and through its alternate
    /// function the capture input of its timer.
    fn drive_probe(&mut self, touching: bool, t: u64) {
        let Some(w) = self.wiring.probe else {
            return;
        };
        self.gpio[w.pin.port].drive(w.pin.pin, Some(touching));
        if self.routed((w.pin, w.af)) {
            if let Some(i) = self.timer_index(w.timer) {
                self.tims[i].capture_input(w.input, touching, t);
            }
        }
    }

    /// When the servo timer's update event starts the first tick after `now`: a whole
    /// number of ticks after the last tick edge (None before the first).
    pub fn next_tick_edge(&self, now: u64) -> Option<u64> {
        let period = crate::time::from_ms(1);
        (self.tick_edge != 0)
            .then(|| self.tick_edge + ((now - self.tick_edge) / period + 1) * period)
    }

    /// Makes the probe changes due by now, each at its own instant, and records them.
    /// Called first in [`Board::process`], at the first block boundary at or after
    /// the instant: a timer a register access of that block already took past it
    /// captures with its counter there (within a block: under one 0.1 µs count of the
    /// probe's capture).
    fn probe_changes(&mut self) {
        while let Some(k) = (0..self.machine.probe_plan.len())
            .filter(|&k| self.machine.probe_plan[k].0 <= self.now)
            .min_by_key(|&k| self.machine.probe_plan[k].0)
        {
            let (t, touching) = self.machine.probe_plan.remove(k);
            if touching == self.machine.probe {
                continue;
            }
            // Everything up to the change's instant first: the drives' steps then,
            // and the capture counter (the servo timer's update events are counted
            // by `process`).
            for tim in &mut self.tims {
                tim.advance(t);
            }
            self.hrtim.advance(t);
            self.collect_pulses();
            self.machine.probe = touching;
            self.drive_probe(touching, t);
            let period = crate::time::from_ms(1);
            let edge = ProbeEdge {
                at: t,
                touching,
                in_tick: t.saturating_sub(self.tick_edge) % period,
                steps: self.machine.joint_steps(),
            };
            self.machine.probe_edges.push(edge);
        }
    }

    /// One plant step of every servo channel (at the servo timer's update event):
    /// each plant under its command (DAC code, amplifier enable), its encoder's
    /// quadrature edges into the encoder counter.
    fn step_plants(&mut self) {
        for c in 0..self.wiring.servos.len() {
            let (sink, source) = self.wiring.servos[c];
            let group = self.wiring.servo_group[c];
            let en_pin = self.wiring.amp_lines[group].0;
            let enabled = self.gpio[en_pin.port].output(en_pin.pin) == Some(true);
            let code = self.command(source);
            let Some(servo) = self.machine.servos[c].as_mut() else {
                continue;
            };
            let before = servo.counts();
            servo.period(code.unwrap_or(0), enabled && code.is_some());
            let after = servo.counts();
            let step = if after >= before { 1 } else { -1 };
            let mut phase = self.machine.phase[c];
            for _ in 0..(after - before).abs() {
                phase = (phase + step).rem_euclid(4);
                // Gray sequence A leading B: 00, 10, 11, 01.
                let (a, b) =
                    [(false, false), (true, false), (true, true), (false, true)][phase as usize];
                self.encoder_edge(sink, a, b);
            }
            self.machine.phase[c] = phase;
        }
    }

    fn analog(&self, pin: Pin) -> bool {
        self.gpio[pin.port].mode(pin.pin) == 3
    }

    fn routed(&self, (pin, af): (Pin, u32)) -> bool {
        let g = &self.gpio[pin.port];
        g.mode(pin.pin) == 2 && g.af(pin.pin) == af
    }

    /// The command code a servo amplifier sees from `source`, if the output reaches
    /// its pin: a DAC channel enabled with its pin in analog mode; a DAC channel
    /// through an OPAMP enabled as follower of the DAC (CSR: OPAMPEN, VP_SEL = 0b11
    /// the DAC, VM_SEL = 0b11 the output; RM0440 OPAMP register map) with its output
    /// pin in analog mode; or HRTIM PWM routed to its pin.
    fn command(&mut self, source: CommandSource) -> Option<u16> {
        match source {
            CommandSource::Dac(d, ch, pin) => {
                (self.dacs[d].enabled(ch) && self.analog(pin)).then(|| self.dacs[d].output(ch))
            }
            CommandSource::Follower(d, ch, op, pin) => {
                let csr = self.opamp.read(4 * op as u32).unwrap_or(0);
                let follower = csr & 1 != 0 && (csr >> 5) & 3 == 3 && (csr >> 2) & 3 == 3;
                (follower && self.dacs[d].enabled(ch) && self.analog(pin))
                    .then(|| self.dacs[d].output(ch))
            }
            CommandSource::HrtimPwm(pin, af) => {
                let now = self.now;
                self.hrtim.advance(now);
                if !self.routed((pin, af)) {
                    return None;
                }
                let code = self.hrtim.duty_code();
                if let Some(c) = code {
                    let r = &mut self.stats.pwm_range;
                    *r = (r.0.min(c), r.1.max(c));
                }
                code
            }
        }
    }

    /// One quadrature edge of an encoder into its counter, through what the board
    /// routes: the pins' alternate functions, COMP4 and TIM4_TISEL, LPTIM1's inputs.
    fn encoder_edge(&mut self, sink: EncoderSink, a: bool, b: bool) {
        match sink {
            EncoderSink::Timer(name, pa, pb) => {
                let Some(i) = self.timer_index(name) else {
                    return;
                };
                let (ha, hb) = self.tims[i].encoder_inputs();
                let a = if self.routed(pa) { a } else { ha };
                let b = if self.routed(pb) { b } else { hb };
                self.tims[i].encoder_input(a, b);
            }
            EncoderSink::TimerComp(name, pa, comp, pb) => {
                let Some(i) = self.timer_index(name) else {
                    return;
                };
                let (ha, hb) = self.tims[i].encoder_inputs();
                let a = if self.routed(pa) { a } else { ha };
                // COMPx_CSR (RM0440 COMP register map): EN bit 0, INMSEL bits 6:4
                // (0b011: VREFINT), POL bit 15; the input pin in analog mode. B's
                // 3.3 V / 0 V against VREFINT's 1.2 V.
                let csr = self.comp.read(4 * comp as u32).unwrap_or(0);
                let on = csr & 1 != 0 && (csr >> 4) & 7 == 3 && self.analog(pb);
                let out = on && (b != (csr & (1 << 15) != 0));
                self.comp_out[comp] = out;
                // TIMx_TISEL.TI2SEL (bits 11:8) = 4: TI2 from COMP4's output.
                let tisel = self.tims[i].read(0x5C, self.now).unwrap_or(0);
                let b = if on && (tisel >> 8) & 0xF == 4 {
                    out
                } else {
                    hb
                };
                self.tims[i].encoder_input(a, b);
            }
            EncoderSink::Lptim(pa, pb) => {
                let (ha, hb) = self.lptim.inputs();
                let a = if self.routed(pa) { a } else { ha };
                let b = if self.routed(pb) { b } else { hb };
                self.lptim.encoder_input(a, b);
            }
        }
    }

    /// The next time something happens on its own.
    pub fn next_event(&self) -> u64 {
        let mut t = u64::MAX;
        for tim in &self.tims {
            if let Some(e) = tim.next_event() {
                t = t.min(e);
            }
        }
        if let Some(e) = self.iwdg.expiry() {
            t = t.min(e);
        }
        if let Some(e) = self.flash.next_event() {
            t = t.min(e);
        }
        for &(e, _) in &self.machine.probe_plan {
            t = t.min(e);
        }
        t
    }

    /// Processes everything due up to now: timer updates (interrupts, the plants'
    /// step), the watchdog, flash operations, the USB interrupt line.
    pub fn process(&mut self) {
        let now = self.now;
        let plant = self.timer_index(PLANT_CLOCK);
        let plant_before = plant.map(|i| self.tims[i].update_events);
        self.probe_changes();
        for i in 0..self.tims.len() {
            let before = match plant_before {
                Some(b) if Some(i) == plant => b,
                _ => self.tims[i].update_events,
            };
            self.tims[i].advance(now);
            if self.tims[i].irq {
                self.tims[i].irq = false;
                match TIMERS[i].3 {
                    Some(line) => {
                        let at = self.tims[i].irq_at;
                        self.scs.pend_irq(line, at);
                        self.pended_in[16 + line] = self.block_pc;
                    }
                    None => self.unmodelled(format!("{} interrupt without a line", TIMERS[i].0)),
                }
            }
            if Some(i) == plant {
                for _ in before..self.tims[i].update_events {
                    self.step_plants();
                }
            }
        }
        self.hrtim.advance(now);
        self.collect_pulses();
        self.flash.advance(now);
        if let Some(t) = self.iwdg.expiry() {
            if now >= t {
                self.reset_due = Some(ResetCause::Watchdog);
            }
        }
        if self.scs.reset_request {
            self.reset_due = Some(ResetCause::Software);
        }
        self.usb_line();
    }

    /// Time passes from `from` to `to` with the core asleep.
    pub fn idle(&mut self, from: u64, to: u64) {
        let period = crate::time::from_ms(1);
        let mut t = from;
        while t < to {
            let end = (t / period + 1) * period;
            let upto = end.min(to);
            self.stats.idle_in_period += upto - t;
            t = upto;
            if t == end {
                self.close_period();
            }
        }
    }

    /// Closes every 1 ms period that `now` has passed.
    pub fn close_periods(&mut self, last: &mut u64) {
        let period = crate::time::from_ms(1);
        while (*last + 1) * period <= self.now {
            *last += 1;
            self.close_period();
        }
    }

    fn close_period(&mut self) {
        let period = crate::time::from_ms(1);
        let idle = self.stats.idle_in_period.min(period);
        let busy = ((period - idle) * 1000 / period) as u16;
        self.stats.busy.push((busy, self.streaming));
        let k = (self.now / period).saturating_sub(1);
        let hist = self.profile.as_mut().map(|p| std::mem::take(&mut p.2));
        if !self.streaming {
            return;
        }
        if let Some(h) = hist {
            if self.worst_profile.as_ref().is_none_or(|w| busy > w.0) {
                self.worst_profile = Some((busy, k, h));
            }
        }
        let w = &mut self.stats.worst_busy;
        if w.len() < 5 || busy > w[w.len() - 1].0 {
            w.push((busy, k, self.block_pc));
            w.sort_by(|a, b| b.0.cmp(&a.0));
            w.truncate(5);
        }
        self.stats.idle_in_period = 0;
    }

    /// Pends the level-sensitive lines (USB_LP, FLASH) while they are asserted and
    /// their handler is not running.
    pub fn usb_line(&mut self) {
        for (level, line) in [(self.usb.irq(), IRQ_USB_LP), (self.flash.irq(), IRQ_FLASH)] {
            let e = crate::nvic::IRQ0 + line as u32;
            if level && !self.scs.active.contains(&e) {
                self.scs.pend_irq(line, self.now);
            }
        }
    }
}
