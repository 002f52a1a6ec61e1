//! The eight-servo wiring (`--features board-servo8`): the hexapod-xy machine, six
//! hydraulic legs through servo valves (channels 0-5) and two X-Y table axes (6, 7),
//! no stepper channel (`docs/wiring.md`, "Eight-servo wiring").
//!
//! Commands. The STM32G474 has seven DAC channels: DAC1 ch1 (PA4), DAC1 ch2 (PA5) and
//! DAC2 ch1 (PA6) reach pins through their own buffers; DAC3 ch1/ch2 and DAC4 ch1/ch2
//! are internal and reach a pin only as the non-inverting input (VINP3) of an OPAMP
//! run as a follower: DAC3 ch2 → OPAMP3 → PB1, DAC4 ch1 → OPAMP4 → PB12, DAC4 ch2 →
//! OPAMP5 → PA8, DAC3 ch1 → OPAMP6 → PB11 (RM0440, OPAMP "signal routing"; VOUT pins
//! also in stm32-metapac 21). The eighth command, channel 7, is PWM from HRTIM1 timer A
//! output 2 (PA9) at 332 kHz with 4096 steps (12 bits, as the DACs), made analog by
//! an external 2nd-order RC filter ([`PwmCommand`]; circuit and numbers in the wiring
//! doc). Code 2048 is zero command on every channel.
//!
//! Encoders. The timers with an encoder interface are TIM1, TIM2, TIM3, TIM4, TIM5,
//! TIM8 and TIM20, and LPTIM1 has an encoder mode (RM0440, LPTIM implementation
//! table): eight counters, but in LQFP64 TIM4 CH2 is only on PB7 (besides USB's PA12),
//! TIM20 CH2 only on PC2 and LPTIM1 IN2 only on PB7 or PC2 (stm32-metapac 21), so
//! the three cannot all take their second input from a pin. TIM4 takes it from
//! comparator COMP4 instead (TIM4_TISEL.TI2SEL = COMP4_OUT, RM0440 general-purpose
//! timers, TIMx_TISEL; ST's G4 HAL names the value `TIM_TIM4_TI2_COMP4`), whose
//! non-inverting input PB0 receives encoder 6's B phase and compares it with VREFINT
//! (1.2 V). Legs: TIM1, TIM2, TIM3, TIM5, TIM8, TIM20; table: TIM4 (A on PB6, B via
//! COMP4) and LPTIM1 (PB5/PB7). All count x4 with a 16-bit wrap.
//!
//! Amplifier lines: one enable and one fault line for the legs, one of each for the
//! table ([`GROUP_OF`]). The touch probe: PA2, TIM15 CH1's input capture
//! (`crate::probe`; TIM15 is otherwise unused here). Pins without embassy pin traits
//! in this build: PA9 (HRTIM1_CHA2, AF13), PB5/PB7 (LPTIM1_IN1/IN2, AF11) and PA2
//! (TIM15_CH1, AF9); their AF numbers are the constants below, checked against
//! stm32-metapac 21.

use embassy_stm32::comp::{self, Comp, Hysteresis, InvertingInput};
use embassy_stm32::gpio::{AfType, Flex, Level, Output, Pull, Speed};
use embassy_stm32::interrupt::{self, InterruptExt};
use embassy_stm32::pac;
use embassy_stm32::pac::dac::vals::Mode as DacMode;
use embassy_stm32::pac::timer::vals::{CcmrInputCcs, Sms};
use embassy_stm32::peripherals::{
    COMP4, DAC1, DAC2, DAC3, DAC4, HRTIM1, OPAMP3, OPAMP4, OPAMP5, OPAMP6, PA4, PA5, PA6, PA8, PA9,
    PB1, PB11, PB12, RCC, TIM4,
};
use embassy_stm32::timer::{Ch1, TimerPin};
use embassy_stm32::{bind_interrupts, Peri, Peripherals};
use pkmc::config::{BoardChannels, Drive, MachineConfig, MAX_SERVOS};
use pkmc::controller::Outputs;
use pkmc::drive::servo::DAC_MID;

use super::{
    analog, claim_timer, clock_analog, encoder, groups_in_range, hrtim_cha2_pin, lptim_encoder,
    probe_capture, start_common, start_dacs, start_followers, AmpLines, Board, Switches,
};
use crate::encoders::{Counter, Encoders};

/// Servo channels this wiring drives: all of the core's.
pub const SERVO_CHANNELS: usize = 8;
const _: () = assert!(SERVO_CHANNELS == MAX_SERVOS);
/// The channels a machine may use on this wiring: no stepper channel, servo channels
/// 0..8.
pub const CHANNELS: BoardChannels = BoardChannels {
    steppers: 0,
    servos: SERVO_CHANNELS as u8,
};
/// Amplifier group of each channel: 0 the legs (SERVO_EN_LEGS, SERVO_FAULT_LEGS), 1
/// the table axes (SERVO_EN_TABLE, SERVO_FAULT_TABLE).
const GROUP_OF: [u8; MAX_SERVOS] = [0, 0, 0, 0, 0, 0, 1, 1];
const _: () = assert!(groups_in_range(&GROUP_OF, 2));

/// USB packets the link takes in a millisecond (`crate::firmware`'s receive pacing):
/// two. The eight servo loops with the five-axis contour control take about 31 % of
/// every millisecond here, and with four packets a connection's queue fill pushed the
/// busiest millisecond to 65 % (the virtual board); the executor runs at most some
/// 130 dense blocks a second on this machine, far below what two packets carry.
pub const RECEIVE_PACKETS_PER_MS: u32 = 2;

/// The touch probe's capture timer: TIM15, which this wiring does not otherwise use,
/// channel 1 ([`PROBE_CHANNEL`]) on PA2 ([`TIM15_CH1_AF`]). TIM15's registers up to
/// CCR2 have the general-purpose 16-bit layout (RM0440, TIM15 register map).
// SAFETY: the address is TIM15's, and only `crate::probe` touches it.
pub const PROBE_TIMER: pac::timer::TimGp16 =
    unsafe { pac::timer::TimGp16::from_ptr(pac::TIM15.as_ptr()) };
/// The probe's capture channel of [`PROBE_TIMER`], 0-based: CH1.
pub const PROBE_CHANNEL: usize = 0;
/// Alternate function of TIM15_CH1 on PA2 (stm32-metapac 21, STM32G474RE); embassy's
/// timer pin traits cover four-channel timers only.
const TIM15_CH1_AF: u8 = 9;

/// Alternate function of LPTIM1_IN1 on PB5 and of LPTIM1_IN2 on PB7 (stm32-metapac 21,
/// STM32G474RE); embassy-stm32 has no pin traits for LPTIM inputs.
const LPTIM1_IN_AF: u8 = 11;
/// TIM4_TISEL.TI2SEL value that takes TI2 from COMP4's output (RM0440, TIMx_TISEL of
/// TIM2/3/4/5: tim_ti2_in4; ST's STM32G4 HAL `TIM_TIM4_TI2_COMP4`).
const TIM4_TI2_FROM_COMP4: u8 = 4;

bind_interrupts!(
    /// COMP4's interrupt, which embassy's comparator driver wants bound for its
    /// edge waits; this board never waits on an edge (the line is disabled again).
    struct CompIrqs {
        COMP4_5_6 => comp::InterruptHandler<COMP4>;
    }
);

/// The machine the controller starts with when flash holds none (or one this wiring
/// cannot run): the built-in Cartesian machine with its three joints on servo channels
/// 0-2 and no gain ([`pkmc::config::ServoConfig::NONE`]): the loops command zero,
/// so the legs' amplifiers are enabled at zero command (the valves at null) whenever
/// the controller is not in e-stop. A stand-in that lets the host connect and load
/// the real machine, which it should do before the hydraulics are powered.
pub fn builtin_machine() -> MachineConfig {
    let mut m = MachineConfig::cartesian_xyz();
    for (channel, joint) in (0..).zip(m.joints.iter_mut()) {
        joint.drive = Drive::Servo { channel };
    }
    m.name.clear();
    let _ = m.name.push_str("servo8-idle");
    m
}

/// Diagnostics of the stepper outputs, of which this wiring has none.
#[derive(Clone, Copy, Debug, Default, defmt::Format)]
pub struct StepStats {
    /// Steps the controller asked for (none: it refuses stepper joints here), not
    /// emitted.
    pub unwired_steps: u32,
}

/// The stepper outputs of a wiring without stepper channels: counts what it is asked.
pub struct Steppers {
    stats: StepStats,
}

impl Steppers {
    /// Counts the steps of `out`, which no channel emits.
    pub fn apply(&mut self, out: &Outputs) {
        for train in &out.steps {
            self.stats.unwired_steps = self.stats.unwired_steps.wrapping_add(train.count);
        }
    }

    /// Diagnostics since start-up.
    pub fn stats(&self) -> StepStats {
        self.stats
    }
}

/// The servo channels' hardware, driven by the servo interrupt: encoders, analog
/// command outputs and the amplifier lines of legs and table.
pub struct ServoIo {
    /// Quadrature encoder counters of the servo channels.
    pub encoders: Encoders,
    /// DAC of channels 0-6 and its channel index (see the module docs).
    dacs: [(pac::dac::Dac, usize); 7],
    /// Channel 7's PWM command.
    pwm: PwmCommand,
    /// Enable and fault lines of the legs (group 0) and the table (group 1).
    amps: AmpLines<2>,
}

impl ServoIo {
    /// Each channel's amplifier fault input: its group's line (true = fault).
    pub fn faults(&self) -> [bool; MAX_SERVOS] {
        self.amps.faults()
    }

    /// Writes the command codes (12-bit; the DACs convert at once, channel 7's PWM
    /// takes its code at the end of the PWM period under way, within 3 µs) and the
    /// group enables, each active while any of its channels' loops is enabled: an
    /// enable goes off before new codes and on after them.
    pub fn write(&mut self, codes: &[u16; MAX_SERVOS], enable: &[bool; MAX_SERVOS]) {
        let on = self.amps.groups(enable);
        self.amps.switch_off(&on);
        for ((dac, channel), &code) in self.dacs.iter().zip(codes) {
            dac.dhr12r(*channel).write(|w| w.set_dhr(code));
        }
        self.pwm.set(codes[7]);
        self.amps.switch_on(&on);
    }
}

/// Sets up every pin, timer, converter and comparator of the pin map, the embassy time
/// base and the watchdog.
///
/// Call once, right after `embassy_stm32::init`, before anything uses embassy-time.
/// The watchdog runs from here on: start the servo timer within
/// [`super::WATCHDOG_MS`].
pub fn init(p: Peripherals) -> Board {
    let (timer, usb) = start_common(p.TIM6, p.TIM7, (p.USB, p.PA12, p.PA11));

    let encoders = Encoders::new([
        encoder(p.TIM1, p.PC0, p.PC1),  // leg 1: TIM1 CH1/CH2, AF2
        encoder(p.TIM2, p.PA15, p.PB3), // leg 2: TIM2 CH1/CH2, AF1
        encoder(p.TIM3, p.PB4, p.PA7),  // leg 3: TIM3 CH1/CH2, AF2
        encoder(p.TIM5, p.PA0, p.PA1),  // leg 4: TIM5 CH1/CH2, AF2
        encoder(p.TIM8, p.PC6, p.PC7),  // leg 5: TIM8 CH1/CH2, AF4
        encoder(p.TIM20, p.PB2, p.PC2), // leg 6: TIM20 CH1 AF3 / CH2 AF6
        comparator_encoder(p.TIM4, p.PB6, p.COMP4, p.PB0), // table X
        lptim_encoder(p.LPTIM1, p.PB5.into(), p.PB7.into(), LPTIM1_IN_AF), // table Y
    ]);
    // Amplifiers disabled before their command outputs come up (at zero command):
    // enables PB15 (legs) and PB13 (table), faults PB14 (legs) and PC3 (table).
    let amps = AmpLines::new(
        [p.PB15.into(), p.PB13.into()],
        [p.PB14.into(), p.PC3.into()],
        GROUP_OF,
    );
    start_dac_outputs(
        (p.DAC1, p.DAC2, p.DAC3, p.DAC4),
        (p.OPAMP3, p.OPAMP4, p.OPAMP5, p.OPAMP6),
        (p.PA4, p.PA5, p.PA6, p.PB1, p.PB12, p.PA8, p.PB11),
    );
    let servo = ServoIo {
        encoders,
        dacs: [
            (pac::DAC1, 0), // 0: PA4
            (pac::DAC1, 1), // 1: PA5
            (pac::DAC2, 0), // 2: PA6
            (pac::DAC3, 1), // 3: OPAMP3 → PB1
            (pac::DAC4, 0), // 4: OPAMP4 → PB12
            (pac::DAC4, 1), // 5: OPAMP5 → PA8
            (pac::DAC3, 0), // 6: OPAMP6 → PB11
        ],
        pwm: PwmCommand::start(p.HRTIM1, p.PA9, &p.RCC),
        amps,
    };

    let switches = Switches::new(
        p.PA10.into(),
        [
            p.PC10.into(),
            p.PC11.into(),
            p.PD2.into(),
            p.PC12.into(),
            p.PC8.into(),
            p.PB9.into(),
            p.PB10.into(),
            p.PC9.into(),
        ],
    );
    // PC5 is spare: left in its reset state (analog).
    let _ = p.PC5;
    let probe = probe_capture(p.TIM15, p.PA2.into(), TIM15_CH1_AF);

    Board {
        flash: super::flash(p.FLASH),
        usb,
        // LD2 (PA5) is a DAC output here: the heartbeat goes to an LED on PC4.
        led: Output::new(p.PC4, Level::Low, Speed::Low),
        steppers: Steppers {
            stats: StepStats::default(),
        },
        switches,
        servo,
        timer,
        probe,
    }
}

/// The pins of the seven DAC commands, channel order.
type CommandPins = (
    Peri<'static, PA4>,
    Peri<'static, PA5>,
    Peri<'static, PA6>,
    Peri<'static, PB1>,
    Peri<'static, PB12>,
    Peri<'static, PA8>,
    Peri<'static, PB11>,
);

/// Brings up the seven DAC command outputs at mid-scale (zero command): DAC1 ch1/ch2
/// and DAC2 ch1 through their own output buffers to PA4, PA5, PA6; DAC3 and DAC4
/// (internal, unbuffered) into OPAMP3-6 as followers driving PB1, PB12, PA8, PB11.
fn start_dac_outputs(
    _dacs: (
        Peri<'static, DAC1>,
        Peri<'static, DAC2>,
        Peri<'static, DAC3>,
        Peri<'static, DAC4>,
    ),
    _opamps: (
        Peri<'static, OPAMP3>,
        Peri<'static, OPAMP4>,
        Peri<'static, OPAMP5>,
        Peri<'static, OPAMP6>,
    ),
    pins: CommandPins,
) {
    analog(Flex::new(pins.0));
    analog(Flex::new(pins.1));
    analog(Flex::new(pins.2));
    analog(Flex::new(pins.3));
    analog(Flex::new(pins.4));
    analog(Flex::new(pins.5));
    analog(Flex::new(pins.6));
    clock_analog();
    start_dacs(&[
        (pac::DAC1, 0, DacMode::NORMAL_EXT_BUFEN),
        (pac::DAC1, 1, DacMode::NORMAL_EXT_BUFEN),
        (pac::DAC2, 0, DacMode::NORMAL_EXT_BUFEN),
        (pac::DAC3, 0, DacMode::NORMAL_INT_BUFDIS),
        (pac::DAC3, 1, DacMode::NORMAL_INT_BUFDIS),
        (pac::DAC4, 0, DacMode::NORMAL_INT_BUFDIS),
        (pac::DAC4, 1, DacMode::NORMAL_INT_BUFDIS),
    ]);
    start_followers(&[pac::OPAMP3, pac::OPAMP4, pac::OPAMP5, pac::OPAMP6]);
}

/// Table X's encoder: TIM4 in encoder mode 3 (x4, 16-bit wrap), A on `a` (PB6,
/// TIM4_CH1) and B through COMP4, whose non-inverting input is `b` (PB0, COMP4_INP0)
/// and inverting input VREFINT, with the largest hysteresis (70 mV): TI2 = COMP4_OUT.
/// The register setup is embassy's `Qei::new`'s, plus the input selection.
fn comparator_encoder(
    tim: Peri<'static, TIM4>,
    a: Peri<'static, impl TimerPin<TIM4, Ch1>>,
    comp: Peri<'static, COMP4>,
    b: Peri<'static, impl comp::InputPlusPin<COMP4> + embassy_stm32::gpio::Pin>,
) -> Counter {
    let config = comp::Config {
        hysteresis: Hysteresis::Hyst70M,
        inverting_input: InvertingInput::Vref,
        ..comp::Config::default()
    };
    // Configured and enabled by `new`; dropping it would disable it.
    core::mem::forget(Comp::new(comp, b, CompIrqs, config));
    interrupt::COMP4_5_6.disable();

    claim_timer(tim);
    let af = a.af_num();
    let mut a = Flex::new(a);
    a.set_as_af_unchecked(af, AfType::input(Pull::None));
    core::mem::forget(a);
    let r = pac::TIM4;
    r.tisel().write(|w| {
        w.set_tisel(0, 0); // TI1: the TIM4_CH1 pin
        w.set_tisel(1, TIM4_TI2_FROM_COMP4);
    });
    r.ccmr_input(0).modify(|w| {
        // 0b01, "normal mapping" (IC1 on TI1, IC2 on TI2): the PAC calls it TI4.
        w.set_ccs(0, CcmrInputCcs::TI4);
        w.set_ccs(1, CcmrInputCcs::TI4);
    });
    r.ccer().modify(|w| {
        w.set_cce(0, true);
        w.set_cce(1, true);
        w.set_ccp(0, false);
        w.set_ccp(1, false);
    });
    r.smcr().modify(|w| w.set_sms(Sms::ENCODER_MODE_3));
    r.arr().write(|w| w.set_arr(u16::MAX));
    r.cr1().modify(|w| w.set_cen(true));
    Counter::Timer(r)
}

/// HRTIM1 timer A's prescaler ratio for the PWM: CKPSC 2, fHRTIM × 8 = 1.36 GHz, one
/// count 0.74 ns (RM0440, HRTIM clock prescaler table).
const PWM_CKPSC: u8 = 2;
/// The ratio without the DLL's delay line (fHRTIM, 5.9 ns), should it not calibrate.
const PWM_CKPSC_NO_DLL: u8 = 5;
/// PWM period, counts: 4096, the DACs' 12 bits (332 kHz at CKPSC 2).
const PWM_PERIOD: u16 = 4096;
/// Smallest compare value at CKPSC 2 (RM0440, HRTIM period and compare limits: 0x18),
/// and the margin kept below the period: codes are clamped to `PWM_MIN..=PWM_MAX`
/// (0.6 % of full scale at either end).
const PWM_MIN: u16 = 0x18;
/// Largest compare value used.
const PWM_MAX: u16 = PWM_PERIOD - PWM_MIN;
// Constant bounds in order: `clamp`'s check folds away, no panic path.
const _: () = assert!(PWM_MIN <= DAC_MID as u16 && DAC_MID as u16 <= PWM_MAX);
/// Timer A.
const PWM_TIMER: usize = 0;
/// Its output 2 (TA2, PA9).
const PWM_OUTPUT: usize = 1;
/// Polls of DLLRDY after starting the DLL calibration (bounded, as for stepper
/// channel 6 of the default wiring).
const PWM_DLL_POLLS: u32 = 100_000;
/// Polls of the update flag after the software update at the start.
const PWM_UPDATE_POLLS: u32 = 32;

/// Channel 7's command: HRTIM1 timer A output 2 on PA9, set at each period start and
/// reset at compare 1, so its duty is code / 4096 (continuous mode; PER, CMP1 and the
/// set/reset sources preloaded and transferred at every repetition event, REP = 0:
/// every period, RM0440 HRTIM "registers preload and update"). An external 2nd-order
/// RC low-pass turns it into 0-3.3 V. Written by the servo interrupt (one register).
struct PwmCommand {
    /// Timer A of HRTIM1.
    timer: pac::hrtim::HrtimTimx,
}

impl PwmCommand {
    /// Calibrates the DLL, starts the PWM at mid-scale (zero command) and only then
    /// hands PA9 to the HRTIM. Should the DLL not report ready the PWM runs at fHRTIM
    /// (CKPSC 5, 41.5 kHz, 64 times the ripple through the same filter) rather than
    /// leave the amplifier's input at 0 V, which would be full negative command.
    fn start(
        _hrtim: Peri<'static, HRTIM1>,
        pin: Peri<'static, PA9>,
        rcc: &Peri<'static, RCC>,
    ) -> Self {
        embassy_stm32::rcc::enable_and_reset::<HRTIM1>();
        let clock = defmt::unwrap!(embassy_stm32::rcc::clocks(rcc).pclk2_tim.to_hertz());
        let r = pac::HRTIM1;
        r.dllcr().write(|w| w.set_cal(true));
        let dll = (0..PWM_DLL_POLLS).any(|_| r.isr().read().dllrdy());
        let ckpsc = if dll {
            // Periodic recalibration, at the slowest rate (every 2^20 fHRTIM periods).
            r.dllcr().write(|w| {
                w.set_calen(true);
                w.set_calrte(0);
            });
            PWM_CKPSC
        } else {
            defmt::warn!("HRTIM1 DLL not ready: servo channel 7's PWM runs at 41.5 kHz");
            PWM_CKPSC_NO_DLL
        };
        let t = r.tim(PWM_TIMER);
        // The prescaler first, with the timer stopped; then the preload registers.
        t.cr().write(|w| {
            w.set_ckpsc(ckpsc);
            w.set_cont(true);
            w.set_preen(true);
            w.set_repu(true);
        });
        t.per().write(|w| w.set_per(PWM_PERIOD));
        t.cmp(0).write(|w| w.set_cmp(DAC_MID as u16));
        t.rep().write(|w| w.set_rep(0));
        t.setr(PWM_OUTPUT).write(|w| w.set_per(true));
        t.rstr(PWM_OUTPUT).write(|w| w.set_cmp(0, true));
        // Preload → active now.
        r.cr2().write(|w| w.set_tswu(PWM_TIMER, true));
        if !(0..PWM_UPDATE_POLLS).any(|_| t.isr().read().upd()) {
            defmt::warn!("HRTIM1 timer A: start-up update not confirmed");
        }
        r.oenr().write(|w| w.set_t2oen(PWM_TIMER, true));
        r.mcr().modify(|w| w.set_tcen(PWM_TIMER, true));
        // fHRCK / fHRTIM: 8 at CKPSC 2, 1 at CKPSC 5.
        let ratio = if dll { 8 } else { 1 };
        defmt::info!(
            "servo channel 7: PWM at {} Hz",
            clock.0 * ratio / u32::from(PWM_PERIOD)
        );
        hrtim_cha2_pin(pin);
        Self { timer: t }
    }

    /// Sets the duty to `code` / 4096, from the next PWM period on.
    #[inline]
    fn set(&self, code: u16) {
        let compare = code.clamp(PWM_MIN, PWM_MAX);
        self.timer.cmp(0).write(|w| w.set_cmp(compare));
    }
}
