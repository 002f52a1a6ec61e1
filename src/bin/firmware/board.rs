//! The NUCLEO-G474RE board: with its two modules the only code that names pins, timers,
//! converters or interrupts.
//!
//! One MCU board, two wirings, chosen when the firmware is built (`docs/wiring.md` has
//! both maps as wiring tables; keep them in step):
//!
//! - the default, `board/mixed.rs`: seven stepper channels and four servo channels;
//! - `--features board-servo8`, `board/servo8.rs`: the hexapod-xy machine, eight servo
//!   channels (six hydraulic legs, two X-Y table axes) and no stepper channel.
//!
//! This file holds what both share: the clock tree, the USB device, the switch inputs,
//! the servo-period timer (TIM7) and the tick it paces, the embassy time base (TIM6),
//! the watchdog, the interrupt handlers and priorities, and the helpers that bring up
//! DACs, op-amp followers, encoder timers and the amplifier lines. Each wiring's module
//! has its pin map (as typed embassy pins where embassy has the pin traits, so a pin
//! without the named alternate function does not compile), its [`ServoIo`], its
//! [`Steppers`] and its [`CHANNELS`], which the controller checks every machine
//! against: a machine on a channel the build does not wire is refused, naming the joint.
//! Alternate functions were checked against stm32-metapac 21 (stm32-data) for the
//! STM32G474RE, connector positions against the NUCLEO-G474RE user manual (UM2505).
//!
//! Invariants: the STM32G474RE in LQFP64 has 38 GPIOs left once SWD (PA13/PA14), the
//! ST-LINK virtual COM port (PA2/PA3), the HSE and LSE crystals (PF0/PF1, PC14/PC15),
//! BOOT0 (PB8), the user button (PC13), the LED (PA5) and USB (PA11/PA12) are set
//! aside; the default wiring uses all 38, the eight-servo wiring takes the LED's PA5 as
//! a DAC output and leaves two spare. Both take PA2, the virtual COM port's transmit
//! line, for the touch probe's timer capture (`crate::probe`). Both keep TIM7 for the 10 kHz servo period,
//! which also paces the 1 kHz interpolation tick (run on the otherwise unused `UCPD1`
//! vector), and TIM6 for the embassy time base; the IWDG watches both interrupts.
//!
//! Interrupt priorities (lower number = more urgent):
//!
//! | priority | interrupt | work |
//! |---|---|---|
//! | 0 | `TIM7_DAC` | servo period, 10 kHz: encoders, loops, DACs; pends the tick every 10th |
//! | 1 | `UCPD1` (software) | interpolation tick, 1 kHz: step trains, switches, controller |
//! | 2 | `USB_LP` | USB device |
//! | 3 | `TIM6_DAC` | embassy time base |
//! | 3 | `FLASH` | end of a flash erase or write: wakes the store task |
//!
//! Why a software-pended tick rather than a second timer: no timer is free in the
//! default wiring, and pending the tick from the servo interrupt makes it run exactly
//! every [`pkmc::drive::servo::SERVO_PER_TICK`]th servo period, so the servo loops load each
//! tick's targets at a fixed phase. The servo interrupt is the most urgent so that the
//! tick (tens to hundreds of µs of planning and kinematics) never delays a servo
//! period; the controller and the tick's data are shared with thread-mode tasks under a
//! priority-ceiling lock at [`TICK_PRIORITY`] ([`crate::shared`]), which masks the
//! tick, USB and the time base but never the servo interrupt. Global critical
//! sections (embassy's drivers, the time driver, defmt, the servo/tick exchange) do
//! mask it, and are all short.
//!
//! The step trains need no interrupt of their own: every STEP timer, HRTIM1 included,
//! ends its train in hardware (`crate::steppers`), so nothing has to outrank the servo
//! interrupt. An interrupt could not end an HRTIM train exactly anyway: the servo
//! interrupt runs inside a global critical section, which holds off every other
//! interrupt, whatever its priority, for its whole run.

use crate::time_driver::{BASIC_TIMER_COUNT_HZ, TIME_BASE};
use embassy_stm32::gpio::{AfType, AnyPin, Flex, Input, Level, Output, OutputType, Pull, Speed};
use embassy_stm32::interrupt;
use embassy_stm32::interrupt::{InterruptExt, Priority};
use embassy_stm32::pac;
use embassy_stm32::pac::dac::vals::Mode as DacMode;
use embassy_stm32::pac::iwdg::vals::{Key, Pr};
use embassy_stm32::pac::opamp::vals::{VmSel, VpSel};
use embassy_stm32::peripherals::{self, PA11, PA12, USB};
use embassy_stm32::time::Hertz;
use embassy_stm32::timer::low_level::Timer as LowLevelTimer;
use embassy_stm32::timer::qei::{self, Qei};
use embassy_stm32::timer::{Ch1, Ch2, CoreInstance, GeneralInstance4Channel, TimerPin};
use embassy_stm32::usb::{self, Driver};
use embassy_stm32::{bind_interrupts, Config, Peri};
use pkmc::config::MAX_SERVOS;
use pkmc::drive::servo::{DAC_MID, SERVO_HZ};

#[cfg(not(feature = "board-servo8"))]
mod mixed;
#[cfg(not(feature = "board-servo8"))]
pub use mixed::{
    builtin_machine, init, ServoIo, StepStats, Steppers, CHANNELS, PROBE_CHANNEL, PROBE_TIMER,
    RECEIVE_PACKETS_PER_MS, SERVO_CHANNELS,
};

#[cfg(feature = "board-servo8")]
mod servo8;
#[cfg(feature = "board-servo8")]
pub use servo8::{
    builtin_machine, init, ServoIo, StepStats, Steppers, CHANNELS, PROBE_CHANNEL, PROBE_TIMER,
    RECEIVE_PACKETS_PER_MS, SERVO_CHANNELS,
};

/// USB vendor ID: pid.codes, the open-source vendor ID.
pub const USB_VID: u16 = 0x1209;
/// USB product ID: pid.codes test PID 0x0001 (for development; a released board needs
/// its own PID from pid.codes).
pub const USB_PID: u16 = 0x0001;
/// USB manufacturer string.
pub const USB_MANUFACTURER: &str = "pkmc";
/// USB product string.
pub const USB_PRODUCT: &str = "pkmc motion controller";
/// USB serial-number string.
pub const USB_SERIAL: &str = "pkmc-g474-0001";

/// Level of the e-stop input while the e-stop is active. The NC contact pulls PA10 to
/// GND; pressing it (or a broken wire) lets the pull-up take the pin high.
pub const ESTOP_ACTIVE: Level = Level::High;
/// Level of a limit/home input while its switch is open (limit or home reached): NC
/// switches to GND with pull-ups, all switches of a joint in series.
pub const LIMIT_ACTIVE: Level = Level::High;
/// Level of a servo-fault input while an amplifier reports a fault: open-collector
/// fault outputs, wired together per line, pulled up on the board.
pub const SERVO_FAULT_ACTIVE: Level = Level::Low;
/// Level of the touch probe's input while the probe touches: a probe whose contacts
/// are closed at rest (NC, to GND, with the pull-up), so that a broken wire reads as
/// touching and a probing move toward a workpiece refuses to start.
pub const PROBE_ACTIVE: Level = Level::High;
/// Level that enables the servo amplifiers on a servo-enable line.
pub const SERVO_ENABLE_ACTIVE: Level = Level::High;

bind_interrupts!(
    /// Interrupts bound to embassy drivers.
    pub struct Irqs {
        USB_LP => usb::InterruptHandler<peripherals::USB>;
        FLASH => embassy_stm32::flash::InterruptHandler;
    }
);

/// The flash driver: asynchronous, so that the store task sleeps through a page
/// erase (about 22 ms each) instead of polling, and the link task runs meanwhile.
pub type BoardFlash = embassy_stm32::flash::Flash<'static, embassy_stm32::flash::Async>;

/// Takes the flash with its end-of-operation interrupt, at the least urgent priority
/// (it only wakes the store task).
pub fn flash(p: Peri<'static, peripherals::FLASH>) -> BoardFlash {
    let flash = embassy_stm32::flash::Flash::new(p, Irqs);
    interrupt::FLASH.set_priority(Priority::P3);
    flash
}

/// The USB driver type.
pub type UsbDriver = Driver<'static, peripherals::USB>;

/// The servo-period timer (basic timer TIM7, IRQ `TIM7_DAC`), at [`SERVO_HZ`].
const SERVO_TIMER: pac::timer::TimBasic = pac::TIM7;

/// Priority of the servo-period interrupt: the most urgent.
const SERVO_PRIORITY: Priority = Priority::P0;
/// Priority of the interpolation tick; also the ceiling of [`crate::shared::TickShared`].
pub const TICK_PRIORITY: Priority = Priority::P1;
/// The tick's interrupt: the NVIC line of the USB Type-C/PD controller UCPD1, which
/// neither wiring uses (its CC pins PB4/PB6 are timer pins in both), pended by software.
const TICK_IRQ: interrupt::Interrupt = interrupt::UCPD1;
const _: () = assert!((SERVO_PRIORITY as u8) < (TICK_PRIORITY as u8));

/// Clock tree: HSE 24 MHz crystal (X3) → PLL (÷6 × 85 ÷ 2) → 170 MHz SYSCLK in range-1
/// boost mode; AHB, APB1 and APB2 undivided (timer kernels at 170 MHz); USB from
/// HSI48 trimmed by the CRS on USB start-of-frame; LPTIM1 (an encoder counter of the
/// eight-servo wiring) on PCLK1, its reset value, made explicit.
pub fn clock_config() -> Config {
    use embassy_stm32::rcc::{
        mux, Hse, HseMode, Hsi48Config, Pll, PllMul, PllPreDiv, PllRDiv, PllSource, Sysclk,
    };
    let mut config = Config::default();
    config.rcc.hse = Some(Hse {
        freq: Hertz(24_000_000),
        mode: HseMode::Oscillator,
    });
    config.rcc.pll = Some(Pll {
        source: PllSource::HSE,
        prediv: PllPreDiv::DIV6, // 4 MHz into the VCO
        mul: PllMul::MUL85,      // 340 MHz VCO
        divp: None,
        divq: None,
        divr: Some(PllRDiv::DIV2), // 170 MHz SYSCLK
    });
    config.rcc.sys = Sysclk::PLL1_R;
    config.rcc.boost = true;
    config.rcc.hsi48 = Some(Hsi48Config {
        sync_from_usb: true,
    });
    config.rcc.mux.clk48sel = mux::Clk48sel::HSI48;
    config.rcc.mux.lptim1sel = mux::Lptimsel::PCLK1;
    config
}

/// The switch inputs, sampled by the tick.
pub struct Switches {
    /// E-stop input (PA10), see [`ESTOP_ACTIVE`].
    estop: Input<'static>,
    /// Limit/home inputs 0..8: input k is joint k's shared home/limit switch.
    limits: [Input<'static>; 8],
}

impl Switches {
    /// The e-stop on `estop` and the limit/home inputs `limits`, with pull-ups.
    fn new(estop: Peri<'static, AnyPin>, limits: [Peri<'static, AnyPin>; 8]) -> Self {
        Self {
            estop: Input::new(estop, Pull::Up),
            limits: limits.map(|pin| Input::new(pin, Pull::Up)),
        }
    }

    /// The raw e-stop input: true = active.
    pub fn estop(&self) -> bool {
        self.estop.get_level() == ESTOP_ACTIVE
    }

    /// The raw limit/home inputs: bit k = input k active.
    pub fn limits(&self) -> u16 {
        let mut bits = 0;
        for (k, input) in self.limits.iter().enumerate() {
            if input.get_level() == LIMIT_ACTIVE {
                bits |= 1 << k;
            }
        }
        bits
    }
}

/// The servo amplifiers' enable outputs and fault inputs, `G` of each: every servo
/// channel belongs to one group, whose enable line is active while any of its channels'
/// loops is enabled and whose fault line (open-collector outputs wired together) is the
/// fault input of all its channels.
pub struct AmpLines<const G: usize> {
    /// Enable output of each group, see [`SERVO_ENABLE_ACTIVE`].
    enable: [Output<'static>; G],
    /// Fault input of each group, see [`SERVO_FAULT_ACTIVE`].
    fault: [Input<'static>; G],
    /// Group of each servo channel (channels the wiring lacks have no loop, so neither
    /// their enable nor their fault matters).
    group_of: [u8; MAX_SERVOS],
}

impl<const G: usize> AmpLines<G> {
    /// Enable lines `enable`, driven inactive at once (before any command output comes
    /// up), fault lines `fault` with pull-ups, and each channel's group.
    fn new(
        enable: [Peri<'static, AnyPin>; G],
        fault: [Peri<'static, AnyPin>; G],
        group_of: [u8; MAX_SERVOS],
    ) -> Self {
        Self {
            enable: enable.map(|pin| Output::new(pin, opposite(SERVO_ENABLE_ACTIVE), Speed::Low)),
            fault: fault.map(|pin| Input::new(pin, Pull::Up)),
            group_of,
        }
    }

    /// The fault input of each servo channel: its group's line (true = fault).
    pub fn faults(&self) -> [bool; MAX_SERVOS] {
        let active: [bool; G] =
            core::array::from_fn(|g| self.fault[g].get_level() == SERVO_FAULT_ACTIVE);
        // A group beyond the lines reads as a fault (it cannot happen: see `new`'s
        // callers' compile-time checks).
        self.group_of
            .map(|g| active.get(usize::from(g)).copied().unwrap_or(true))
    }

    /// Which groups `enable` (per channel) asks to be enabled.
    pub fn groups(&self, enable: &[bool; MAX_SERVOS]) -> [bool; G] {
        core::array::from_fn(|g| {
            self.group_of
                .iter()
                .zip(enable)
                .any(|(&group, &on)| usize::from(group) == g && on)
        })
    }

    /// Drives the enable line of every group that `on` leaves off inactive.
    pub fn switch_off(&mut self, on: &[bool; G]) {
        for (line, &on) in self.enable.iter_mut().zip(on) {
            if !on {
                line.set_level(opposite(SERVO_ENABLE_ACTIVE));
            }
        }
    }

    /// Drives the enable line of every group that `on` turns on active.
    pub fn switch_on(&mut self, on: &[bool; G]) {
        for (line, &on) in self.enable.iter_mut().zip(on) {
            if on {
                line.set_level(SERVO_ENABLE_ACTIVE);
            }
        }
    }
}

/// Is every entry of a channel-to-group table a group of `groups`? For the compile-time
/// checks of the wirings' tables.
const fn groups_in_range(group_of: &[u8; MAX_SERVOS], groups: usize) -> bool {
    let mut c = 0;
    while c < MAX_SERVOS {
        if group_of[c] as usize >= groups {
            return false;
        }
        c += 1;
    }
    true
}

/// The servo-period timer, configured and waiting for [`ServoTimer::start`].
pub struct ServoTimer {
    _private: (),
}

impl ServoTimer {
    /// Starts the servo period: from now on `TIM7_DAC` fires every 1 / [`SERVO_HZ`] s at
    /// priority 0 and the tick can be pended on its vector at priority 1. The probe's
    /// capture counter starts right before the servo timer, with two register writes
    /// and no interrupt between them: it leads it by those few kernel cycles, under one
    /// of its 17-cycle counts ([`crate::probe`]).
    pub fn start(self) {
        TICK_IRQ.set_priority(TICK_PRIORITY);
        interrupt::TIM7_DAC.set_priority(SERVO_PRIORITY);
        // SAFETY: both handlers below take only critical sections and the
        // priority-ceiling lock of `crate::shared`, whose ceiling is the tick's own
        // priority; the servo handler never takes that lock.
        unsafe {
            TICK_IRQ.enable();
            interrupt::TIM7_DAC.enable();
        }
        critical_section::with(|_| {
            let mut probe = PROBE_TIMER.cr1().read();
            probe.set_cen(true);
            let mut servo = SERVO_TIMER.cr1().read();
            servo.set_cen(true);
            PROBE_TIMER.cr1().write_value(probe);
            SERVO_TIMER.cr1().write_value(servo);
        });
    }
}

/// Pends the interpolation tick (it runs once the servo interrupt returns).
pub fn pend_tick() {
    TICK_IRQ.pend();
}

/// Everything [`init`] hands to the rest of the firmware.
pub struct Board {
    /// USB full-speed device on PA11 (D−) / PA12 (D+).
    pub usb: UsbDriver,
    /// The heartbeat LED, active high.
    pub led: Output<'static>,
    /// STEP/DIR channels and the shared stepper ENABLE (none on the eight-servo wiring).
    pub steppers: Steppers,
    /// E-stop and limit/home inputs.
    pub switches: Switches,
    /// Encoders, analog outputs, enables and faults of the servo channels.
    pub servo: ServoIo,
    /// The servo period (and with it the tick), ready to start.
    pub timer: ServoTimer,
    /// The flash, for the machine-configuration page ([`CONFIG_PAGE_OFFSET`]).
    pub flash: BoardFlash,
    /// The touch probe's input and its capture.
    pub probe: crate::probe::Probe,
}

/// Offset (from the start of flash) of the page that keeps the machine configuration:
/// the last 4 KB of the 512 KB flash, bank 2's last two 2 KB pages (dual-bank mode,
/// the factory setting, see `memory.x`); `memory.x` ends the program region before it.
pub const CONFIG_PAGE_OFFSET: u32 = 508 * 1024;
/// Size of that region (two 2 KB pages, erased together).
pub const CONFIG_PAGE_BYTES: u32 = 4 * 1024;

/// What both wirings set up first: the watchdog (running from here on: start the servo
/// timer within [`WATCHDOG_MS`]), the embassy time base on TIM6, the servo timer TIM7
/// (stopped) and the USB driver on PA12 (D+) / PA11 (D−).
fn start_common(
    tim6: Peri<'static, peripherals::TIM6>,
    tim7: Peri<'static, peripherals::TIM7>,
    usb: (Peri<'static, USB>, Peri<'static, PA12>, Peri<'static, PA11>),
) -> (ServoTimer, UsbDriver) {
    start_watchdog();
    start_time_base(tim6);
    let timer = configure_servo_timer(tim7);
    let usb = Driver::new(usb.0, Irqs, usb.1, usb.2);
    interrupt::USB_LP.set_priority(Priority::P2);
    (timer, usb)
}

/// DAC_MCR.HFSEL for the 170 MHz AHB clock of [`clock_config`]: 0b10, "AHB clock
/// above 160 MHz" (RM0440, DAC mode control register).
const DAC_HFSEL: u8 = 0b10;
/// Polls of DAC_SR.DACRDY before giving up waiting: far beyond the DAC's wake-up time
/// (a few µs; one poll is at least a few cycles at 170 MHz).
const DAC_READY_POLLS: u32 = 10_000;

/// Puts `pin` in analog mode (its reset state, made explicit) and keeps it so for good.
fn analog(mut pin: Flex<'static>) {
    pin.set_as_analog();
    core::mem::forget(pin);
}

/// Turns on the clocks of DAC1–DAC4 and of the OPAMP and COMP registers (clocked with
/// SYSCFG, RCC_APB2ENR.SYSCFGEN), reading them back so that they run before the first
/// register access.
fn clock_analog() {
    pac::RCC.ahb2enr().modify(|w| {
        w.set_dac1en(true);
        w.set_dac2en(true);
        w.set_dac3en(true);
        w.set_dac4en(true);
    });
    pac::RCC.apb2enr().modify(|w| w.set_syscfgen(true));
    let _ = pac::RCC.ahb2enr().read();
    let _ = pac::RCC.apb2enr().read();
}

/// Brings up DAC `channels` (DAC, channel index, mode) at mid-scale (zero command),
/// register level: the servo interrupt then writes one data register per channel.
/// Their clocks must run ([`clock_analog`]). No trigger: DHR → DOR at once.
fn start_dacs(channels: &[(pac::dac::Dac, usize, DacMode)]) {
    for &(dac, ch, mode) in channels {
        // Mode and HFSEL are written with the channel disabled; data before enabling,
        // so the output comes up at mid-scale.
        dac.mcr().modify(|w| {
            w.set_hfsel(DAC_HFSEL);
            w.set_mode(ch, mode);
        });
        dac.dhr12r(ch).write(|w| w.set_dhr(DAC_MID as u16));
        dac.cr().modify(|w| w.set_en(ch, true));
    }
    for &(dac, ch, _) in channels {
        let mut polls = 0;
        while !dac.sr().read().dacrdy(ch) && polls < DAC_READY_POLLS {
            polls += 1;
        }
        // Again, now that the channel is on, in case the write to a disabled channel
        // did not reach its output register.
        dac.dhr12r(ch).write(|w| w.set_dhr(DAC_MID as u16));
    }
}

/// Enables `opamps` as voltage followers of their internal DAC channel, output to their
/// VOUT pin: VINP = VINP3 (the one DAC channel each OPAMP can take: OPAMP1 and
/// OPAMP6 DAC3_CH1, OPAMP3 DAC3_CH2, OPAMP4 DAC4_CH1, OPAMP5 DAC4_CH2; RM0440 OPAMP
/// "signal routing"; the PAC names the value after OPAMP1's), VINM = the output. Their
/// register clock must run ([`clock_analog`]) and their DAC channels be up.
fn start_followers(opamps: &[pac::opamp::Opamp]) {
    for opamp in opamps {
        opamp.csr().write(|w| {
            w.set_vp_sel(VpSel::DAC3_CH1);
            w.set_vm_sel(VmSel::OUTPUT);
            w.set_opaintoen(false); // output to the VOUT pin
            w.set_opahsm(false);
            w.set_opampen(true);
        });
    }
}

/// IWDG prescaler: LSI ÷ 8, 4 kHz at the nominal 32 kHz (0.25 ms per count).
const WATCHDOG_PRESCALER: Pr = Pr::DIVIDE_BY8;
/// IWDG reload value: 200 counts (RLR + 1) = 50 ms at the nominal LSI.
const WATCHDOG_RELOAD: u16 = 199;
/// The watchdog timeout at the nominal 32 kHz LSI, ms.
///
/// Why 50 ms: it must outlast a flash page erase should the CPU stall on it. In the
/// dual-bank mode used here it does not: the configuration pages are in bank 2 and
/// the program in bank 1 (read-while-write, RM0440 flash chapter). The margin is kept
/// for a configuration where it would (every flash fetch stalled: nothing runs,
/// neither interrupt refreshes the watchdog). The figures designed for: a page erase takes about 22 ms typical
/// and 40 ms at most (STM32G4 flash characteristics, RM0440 / DS12288; the 40 ms
/// maximum is the one that counts). The store task refreshes the watchdog right before
/// it erases, and the tick refreshes it again within about a millisecond of the stall
/// ending, so the timeout must exceed 40 ms + 1 ms even with the fastest LSI. Taking
/// the LSI spread as about ±6 % (29.5–34 kHz over voltage and temperature), the
/// timeout is 47 ms at 34 kHz, 6 ms above that, and 54 ms at 29.5 kHz. Anything that
/// stalls the servo interrupt or the tick for longer resets the chip.
pub const WATCHDOG_MS: u32 = 50;
const _: () = assert!((WATCHDOG_RELOAD as u32 + 1) * 8 * 1000 / 32_000 == WATCHDOG_MS);

/// Was the last reset caused by the independent watchdog? Reads RCC_CSR.IWDGRSTF and
/// then clears every reset flag (RMVF), so the answer is about this reset only. Call
/// once, first thing at start-up.
pub fn take_watchdog_reset() -> bool {
    let watchdog = pac::RCC.csr().read().iwdgrstf();
    pac::RCC.csr().modify(|w| w.set_rmvf(true));
    watchdog
}

/// Starts the independent watchdog (LSI, [`WATCHDOG_MS`]); it cannot be stopped again
/// (RM0440, IWDG). It is frozen while a debugger halts the core.
fn start_watchdog() {
    pac::DBGMCU.apb1lfzr().modify(|w| w.set_iwdg(true));
    let iwdg = pac::IWDG;
    iwdg.kr().write(|w| w.set_key(Key::START));
    iwdg.kr().write(|w| w.set_key(Key::ENABLE));
    iwdg.pr().write(|w| w.set_pr(WATCHDOG_PRESCALER));
    iwdg.rlr().write(|w| w.set_rl(WATCHDOG_RELOAD));
    // The new values reach the LSI domain within a few LSI periods (SR clears); the
    // refresh below then loads the new reload value. Bounded: the default timeout
    // (512 ms) covers the wait anyway.
    let mut polls = 0u32;
    while iwdg.sr().read().0 != 0 && polls < 1_000_000 {
        polls += 1;
    }
    feed_watchdog();
}

/// Refreshes the independent watchdog.
pub fn feed_watchdog() {
    pac::IWDG.kr().write(|w| w.set_key(Key::RESET));
}

/// The other logic level.
fn opposite(level: Level) -> Level {
    match level {
        Level::Low => Level::High,
        Level::High => Level::Low,
    }
}

/// Clocks and resets `tim` for direct register use and keeps it clocked for good.
fn claim_timer<T: GeneralInstance4Channel>(tim: Peri<'static, T>) -> Hertz {
    let timer = LowLevelTimer::new(tim);
    let clock = timer.get_clock_frequency();
    // Dropping the driver would stop the timer's clock; the firmware owns it forever.
    core::mem::forget(timer);
    clock
}

/// Alternate function of HRTIM1_CHA2 on PA9 (stm32-metapac 21, STM32G474RE): STEP6 of
/// the default wiring, the filtered-PWM command of servo channel 7 of the eight-servo
/// one. embassy-stm32's HRTIM pin traits come with its `stm32-hrtim` feature, which this
/// build does not enable, so the pin is fixed by type and its AF number by this constant.
pub const HRTIM1_CHA2_AF: u8 = 13;

/// Hands PA9 to HRTIM1 timer A output 2 ([`HRTIM1_CHA2_AF`]) for good.
fn hrtim_cha2_pin(pin: Peri<'static, peripherals::PA9>) {
    let mut pin = Flex::new(pin);
    pin.set_as_af_unchecked(
        HRTIM1_CHA2_AF,
        AfType::output(OutputType::PushPull, Speed::VeryHigh),
    );
    // Dropping the pin would disconnect it.
    core::mem::forget(pin);
}

/// A quadrature encoder on timer `tim` (CH1 = A, CH2 = B), counting all four edges with
/// a 16-bit wrap.
fn encoder<T: GeneralInstance4Channel>(
    tim: Peri<'static, T>,
    a: Peri<'static, impl TimerPin<T, Ch1>>,
    b: Peri<'static, impl TimerPin<T, Ch2>>,
) -> crate::encoders::Counter {
    let qei = Qei::new(tim, a, b, qei::Config::default());
    // Dropping the driver would stop the timer's clock and float the pins.
    core::mem::forget(qei);
    // SAFETY: every encoder timer has at least the general-purpose 16-bit layout; the
    // firmware only reads its counter.
    crate::encoders::Counter::Timer(unsafe { pac::timer::TimGp16::from_ptr(T::regs()) })
}

/// The touch probe on `pin` (alternate function `af` of [`PROBE_TIMER`]'s channel
/// [`PROBE_CHANNEL`], input with the pull-up: see [`PROBE_ACTIVE`]), its timer `tim`
/// clocked and set up as the capture ([`crate::probe`]), stopped until
/// [`ServoTimer::start`].
fn probe_capture<T: CoreInstance>(
    tim: Peri<'static, T>,
    pin: Peri<'static, AnyPin>,
    af: u8,
) -> crate::probe::Probe {
    let timer = LowLevelTimer::new(tim);
    let clock = timer.get_clock_frequency();
    // Dropping the driver would stop the timer's clock; the firmware owns it forever.
    core::mem::forget(timer);
    defmt::assert!(T::regs() == PROBE_TIMER.as_ptr());
    let mut pin = Flex::new(pin);
    pin.set_as_af_unchecked(af, AfType::input(Pull::Up));
    crate::probe::Probe::new(clock.0, pin)
}

/// An encoder on LPTIM1 in encoder mode on IN1 and IN2 (alternate function `af` of
/// both pins), counting both edges of both inputs (x4) between 0 and ARR = 0xFFFF (a
/// 16-bit wrap), clocked by PCLK1 at 170 MHz (each input may toggle at up to a quarter
/// of that). RM0440, LPTIM "Encoder mode": internal clock (CKSEL 0), prescaler 1,
/// continuous mode; CFGR is written while the LPTIM is disabled, ARR only while it is
/// enabled.
fn lptim_encoder(
    _lptim: Peri<'static, peripherals::LPTIM1>,
    in1: Peri<'static, AnyPin>,
    in2: Peri<'static, AnyPin>,
    af: u8,
) -> crate::encoders::Counter {
    use embassy_stm32::pac::lptim::vals::{Ckpol, ClockSource, Presc};
    embassy_stm32::rcc::enable_and_reset::<peripherals::LPTIM1>();
    let l = pac::LPTIM1;
    l.cfgr().write(|w| {
        w.set_cksel(ClockSource::INTERNAL);
        w.set_ckpol(Ckpol::BOTH);
        w.set_presc(Presc::DIV1);
        w.set_enc(true);
    });
    l.cr().write(|w| w.set_enable(true));
    l.arr().write(|w| w.set_arr(u16::MAX));
    let mut polls = 0;
    while !l.isr().read().arrok() && polls < LPTIM_ARR_POLLS {
        polls += 1;
    }
    l.icr().write(|w| w.set_arrokcf(true));
    l.cr().write(|w| {
        w.set_enable(true);
        w.set_cntstrt(true);
    });
    for pin in [in1, in2] {
        let mut pin = Flex::new(pin);
        pin.set_as_af_unchecked(af, AfType::input(Pull::None));
        core::mem::forget(pin);
    }
    crate::encoders::Counter::LowPower(l)
}

/// Polls of LPTIM_ISR.ARROK after writing LPTIM_ARR: the write crosses into the kernel
/// clock domain within a few of its cycles (PCLK1 here).
const LPTIM_ARR_POLLS: u32 = 10_000;

/// Programs a basic timer to count at [`BASIC_TIMER_COUNT_HZ`] and overflow at
/// `overflow_hz`, with its update interrupt enabled in the timer (not yet in the NVIC).
fn configure_basic(regs: pac::timer::TimBasic, clock: Hertz, overflow_hz: u32, uif_remap: bool) {
    let prescale = clock.0 / BASIC_TIMER_COUNT_HZ;
    defmt::assert!(
        prescale * BASIC_TIMER_COUNT_HZ == clock.0,
        "timer clock {} Hz",
        clock.0
    );
    regs.cr1().write(|w| {
        w.set_urs(pac::timer::vals::Urs::COUNTER_ONLY);
        w.set_arpe(true);
        w.set_uifremap(uif_remap);
    });
    regs.psc().write_value((prescale - 1) as u16);
    regs.arr()
        .write(|w| w.set_arr((BASIC_TIMER_COUNT_HZ / overflow_hz - 1) as u16));
    regs.cnt().write(|w| w.set_cnt(0));
    regs.egr().write(|w| w.set_ug(true));
    regs.sr().write(|w| w.set_uif(false));
    regs.dier().write(|w| w.set_uie(true));
}

/// Starts TIM6 as the embassy time base: 1 MHz count, overflow every millisecond.
fn start_time_base(tim: Peri<'static, peripherals::TIM6>) {
    let timer = LowLevelTimer::new(tim);
    let clock = timer.get_clock_frequency();
    core::mem::forget(timer);
    configure_basic(TIME_BASE, clock, crate::time_driver::PERIOD_HZ, true);
    TIME_BASE.cr1().modify(|w| w.set_cen(true));
    interrupt::TIM6_DAC.set_priority(Priority::P3);
    // SAFETY: the handler only takes critical sections.
    unsafe { interrupt::TIM6_DAC.enable() };
}

/// Prepares TIM7 as the servo-period timer ([`SERVO_HZ`]), stopped.
fn configure_servo_timer(tim: Peri<'static, peripherals::TIM7>) -> ServoTimer {
    let timer = LowLevelTimer::new(tim);
    let clock = timer.get_clock_frequency();
    core::mem::forget(timer);
    configure_basic(SERVO_TIMER, clock, SERVO_HZ, false);
    ServoTimer { _private: () }
}

/// The servo-period interrupt.
#[interrupt]
fn TIM7_DAC() {
    SERVO_TIMER.sr().write(|w| w.set_uif(false));
    crate::on_servo_period();
}

/// The interpolation tick, pended by [`pend_tick`].
#[interrupt]
fn UCPD1() {
    crate::on_tick();
}

/// The embassy time-base interrupt.
#[interrupt]
fn TIM6_DAC() {
    crate::time_driver::on_overflow();
}
