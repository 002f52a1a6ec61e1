//! The default wiring: seven stepper channels and four servo channels (`docs/wiring.md`,
//! "Stepper channels", "Servo channels" and "Touch probe").
//!
//! Timer use: TIM1, TIM8, TIM20, TIM15, TIM16, TIM17 the STEP trains of stepper
//! channels 0-5; HRTIM1 timer A the STEP train of stepper channel 6; LPTIM1, TIM3,
//! TIM4, TIM5 the encoders of servo channels 0-3, whose commands are DAC1 ch1 (PA4),
//! DAC2 ch1 (PA6), and DAC3 ch2 and DAC4 ch1 through OPAMP3 (PB1) and OPAMP4 (PB12) as
//! followers; TIM2 the touch probe's input capture on PA2 (`crate::probe`). One
//! SERVO_EN line enables every amplifier and one SERVO_FAULT line is every
//! amplifier's fault. Servo channels 4-7 of the core are not wired ([`CHANNELS`]): a
//! machine using one is refused. Pins not typed by their function: PA9
//! (HRTIM1_CHA2, see [`super::HRTIM1_CHA2_AF`]), PC0/PC2 (LPTIM1_IN1/IN2) and PA2
//! (TIM2_CH3, whose AF number is checked against embassy's typed pin).

use embassy_stm32::gpio::{AnyPin, Flex, Level, Output, OutputType, Speed};
use embassy_stm32::pac;
use embassy_stm32::pac::dac::vals::Mode as DacMode;
use embassy_stm32::peripherals::{
    DAC1, DAC2, DAC3, DAC4, HRTIM1, OPAMP3, OPAMP4, PA4, PA6, PA9, PB1, PB12, RCC, TIM2,
};
use embassy_stm32::timer::simple_pwm::PwmPin;
use embassy_stm32::timer::{AdvancedInstance4Channel, Ch1, Ch3, Ch4, TimerChannel, TimerPin};
use embassy_stm32::{Peri, Peripherals};
use pkmc::config::{BoardChannels, MachineConfig, BOARD_STEPS_PER_TICK, MAX_SERVOS, MAX_STEPPERS};

use super::{
    analog, claim_timer, clock_analog, encoder, groups_in_range, hrtim_cha2_pin, lptim_encoder,
    opposite, probe_capture, start_common, start_dacs, start_followers, AmpLines, Board, Switches,
};
use crate::encoders::Encoders;
use crate::steppers::{periods, HrStepTimer, StepChannel, StepOutput, StepTimer};
pub use crate::steppers::{StepStats, Steppers};

/// Servo channels this wiring drives: 0..4.
pub const SERVO_CHANNELS: usize = 4;
/// The channels a machine may use on this wiring: every stepper channel, servo
/// channels 0..4.
pub const CHANNELS: BoardChannels = BoardChannels {
    steppers: MAX_STEPPERS as u8,
    servos: SERVO_CHANNELS as u8,
};
/// One amplifier line of each kind: SERVO_EN enables and SERVO_FAULT reports for every
/// servo channel.
const GROUP_OF: [u8; MAX_SERVOS] = [0; MAX_SERVOS];
const _: () = assert!(groups_in_range(&GROUP_OF, 1));

/// USB packets the link takes in a millisecond (`crate::firmware`'s receive pacing):
/// four (256 bytes, a dozen blocks or more) keep the busiest millisecond of a dense
/// H-4 job near 45 % with its motion time unchanged; two slowed it (the executor takes
/// up to a block a tick, a thousand a second).
pub const RECEIVE_PACKETS_PER_MS: u32 = 4;

/// The touch probe's capture timer: TIM2, freed by servo channel 0's encoder moving to
/// LPTIM1; channel 3 ([`PROBE_CHANNEL`]) on PA2 ([`TIM2_CH3_AF`]).
// SAFETY: the address is TIM2's, and only `crate::probe` touches it; its 32-bit
// counter is used on 16 bits.
pub const PROBE_TIMER: pac::timer::TimGp16 =
    unsafe { pac::timer::TimGp16::from_ptr(pac::TIM2.as_ptr()) };
/// The probe's capture channel of [`PROBE_TIMER`], 0-based: CH3.
pub const PROBE_CHANNEL: usize = 2;
/// Alternate function of TIM2_CH3 on PA2 (stm32-metapac 21, STM32G474RE; embassy's
/// `TimerPin<TIM2, Ch3>` for PA2 says the same, see below).
const TIM2_CH3_AF: u8 = 1;
/// Alternate function of LPTIM1_IN1 on PC0 and of LPTIM1_IN2 on PC2 (stm32-metapac 21,
/// STM32G474RE); embassy-stm32 has no pin traits for LPTIM inputs.
const LPTIM1_IN_AF: u8 = 1;

/// Level that enables the stepper drives on STEP_EN (buffered to every drive's ENABLE).
pub const STEPPER_ENABLE_ACTIVE: Level = Level::High;

/// The machine the controller starts with when flash holds none (or one this wiring
/// cannot run): the built-in Cartesian stepper machine.
pub fn builtin_machine() -> MachineConfig {
    MachineConfig::cartesian_xyz()
}

/// The servo channels' hardware, driven by the servo interrupt: encoders, analog
/// command outputs, the shared amplifier enable and the shared fault input.
pub struct ServoIo {
    /// Quadrature encoder counters of the servo channels.
    pub encoders: Encoders,
    /// DAC of each servo channel and its channel index: DAC1 ch1 (PA4), DAC2 ch1
    /// (PA6), DAC3 ch2 (→ OPAMP3 → PB1), DAC4 ch1 (→ OPAMP4 → PB12).
    dacs: [(pac::dac::Dac, usize); SERVO_CHANNELS],
    /// SERVO_EN (PB5) and SERVO_FAULT (PB11), shared by every channel.
    amps: AmpLines<1>,
}

impl ServoIo {
    /// Each channel's amplifier fault input: the shared line (true = fault).
    pub fn faults(&self) -> [bool; MAX_SERVOS] {
        self.amps.faults()
    }

    /// Writes the DAC codes (12-bit, right-aligned; the DACs convert at once, no
    /// trigger) and the shared enable, active while any channel's loop is enabled: the
    /// enable goes off before new codes and on after them.
    pub fn write(&mut self, codes: &[u16; MAX_SERVOS], enable: &[bool; MAX_SERVOS]) {
        let on = self.amps.groups(enable);
        self.amps.switch_off(&on);
        for ((dac, channel), &code) in self.dacs.iter().zip(codes) {
            dac.dhr12r(*channel).write(|w| w.set_dhr(code));
        }
        self.amps.switch_on(&on);
    }
}

/// Steps per tick of stepper channel `$channel`, whose timer's repetition-counter
/// register `$reg` returns: [`capacity`] evaluated at compile time (a constant item,
/// which `cargo check` evaluates too).
macro_rules! steps_per_tick {
    ($channel:literal, $reg:expr) => {{
        const STEPS: u32 = capacity($channel, periods(|| $reg));
        STEPS
    }};
}

/// Steps per tick of stepper channel `channel`, whose timer's repetition counter
/// counts `periods` ([`periods`]): checked, at compile time, against the core's
/// [`BOARD_STEPS_PER_TICK`], by which machines are validated.
const fn capacity(channel: usize, periods: u32) -> u32 {
    assert!(
        periods == BOARD_STEPS_PER_TICK[channel],
        "a stepper channel's timer disagrees with pkmc::config::BOARD_STEPS_PER_TICK"
    );
    periods
}

/// Stepper channel 6 is HRTIM1 timer A ([`hrtim_step`]).
const _: u32 = capacity(6, periods(|| pac::HRTIM1.tim(0).rep()));

/// Sets up every pin, timer and converter of the pin map, the embassy time base and
/// the watchdog.
///
/// Call once, right after `embassy_stm32::init`, before anything uses embassy-time.
/// The watchdog runs from here on: start the servo timer within
/// [`super::WATCHDOG_MS`].
pub fn init(p: Peripherals) -> Board {
    let (timer, usb) = start_common(p.TIM6, p.TIM7, (p.USB, p.PA12, p.PA11));

    // Stepper channels: STEP on a timer channel, DIR a GPIO (low = reverse).
    let dir = |pin: Peri<'static, AnyPin>| Output::new(pin, Level::Low, Speed::Low);
    let channels = [
        // 0: TIM1_CH1 on PA8 (AF6).
        StepChannel::new(
            step_timer::<_, Ch1>(p.TIM1, p.PA8, steps_per_tick!(0, pac::TIM1.rcr())),
            dir(p.PA0.into()),
        ),
        // 1: TIM8_CH4 on PC9 (AF4).
        StepChannel::new(
            step_timer::<_, Ch4>(p.TIM8, p.PC9, steps_per_tick!(1, pac::TIM8.rcr())),
            dir(p.PC1.into()),
        ),
        // 2: TIM20_CH3 on PC8 (AF6).
        StepChannel::new(
            step_timer::<_, Ch3>(p.TIM20, p.PC8, steps_per_tick!(2, pac::TIM20.rcr())),
            dir(p.PA1.into()),
        ),
        // 3: TIM15_CH1 on PB14 (AF1).
        StepChannel::new(
            step_timer::<_, Ch1>(p.TIM15, p.PB14, steps_per_tick!(3, pac::TIM15.rcr())),
            dir(p.PC3.into()),
        ),
        // 4: TIM16_CH1 on PB4 (AF1).
        StepChannel::new(
            step_timer::<_, Ch1>(p.TIM16, p.PB4, steps_per_tick!(4, pac::TIM16.rcr())),
            dir(p.PC4.into()),
        ),
        // 5: TIM17_CH1 on PA7 (AF1).
        StepChannel::new(
            step_timer::<_, Ch1>(p.TIM17, p.PA7, steps_per_tick!(5, pac::TIM17.rcr())),
            dir(p.PC5.into()),
        ),
        // 6: HRTIM1 timer A output 2 on PA9 (AF13).
        StepChannel::new(hrtim_step(p.HRTIM1, p.PA9, &p.RCC), dir(p.PB13.into())),
    ];
    let enable = Output::new(p.PB15, opposite(STEPPER_ENABLE_ACTIVE), Speed::Low);
    let steppers = Steppers::new(channels, enable, STEPPER_ENABLE_ACTIVE);

    let encoders = Encoders::new([
        lptim_encoder(p.LPTIM1, p.PC0.into(), p.PC2.into(), LPTIM1_IN_AF), // servo 0
        encoder(p.TIM3, p.PC6, p.PC7),  // servo 1: TIM3 CH1/CH2, AF2
        encoder(p.TIM4, p.PB6, p.PB7),  // servo 2: TIM4 CH1/CH2, AF2
        encoder(p.TIM5, p.PB2, p.PC12), // servo 3: TIM5 CH1 AF2 / CH2 AF1
    ]);
    // Amplifiers disabled (SERVO_EN, PB5) before their command outputs come up (at
    // zero command); SERVO_FAULT on PB11.
    let amps = AmpLines::new([p.PB5.into()], [p.PB11.into()], GROUP_OF);
    start_servo_outputs(
        (p.DAC1, p.DAC2, p.DAC3, p.DAC4),
        (p.OPAMP3, p.OPAMP4),
        (p.PA4, p.PA6, p.PB1, p.PB12),
    );
    let servo = ServoIo {
        encoders,
        dacs: [
            (pac::DAC1, 0),
            (pac::DAC2, 0),
            (pac::DAC3, 1),
            (pac::DAC4, 0),
        ],
        amps,
    };

    let switches = Switches::new(
        p.PA10.into(),
        [
            p.PC10.into(),
            p.PC11.into(),
            p.PD2.into(),
            p.PA15.into(),
            p.PB0.into(),
            p.PB9.into(),
            p.PB10.into(),
            p.PB3.into(),
        ],
    );

    // PA2 must be a TIM2_CH3 pin for this to build (embassy's typed pins); a debug
    // build also compares the AF numbers.
    defmt::debug_assert!(TimerPin::<TIM2, Ch3>::af_num(&*p.PA2) == TIM2_CH3_AF);
    let probe = probe_capture(p.TIM2, p.PA2.into(), TIM2_CH3_AF);

    Board {
        probe,
        flash: super::flash(p.FLASH),
        usb,
        led: Output::new(p.PA5, Level::Low, Speed::Low),
        steppers,
        switches,
        servo,
        timer,
    }
}

/// Brings up the four analog command outputs at mid-scale (zero command):
/// DAC1 ch1 → PA4 and DAC2 ch1 → PA6 through the DACs' own output buffers; DAC3 ch2
/// and DAC4 ch1 (internal-only converters, unbuffered) into OPAMP3 and OPAMP4 as
/// voltage followers driving PB1 and PB12.
fn start_servo_outputs(
    _dacs: (
        Peri<'static, DAC1>,
        Peri<'static, DAC2>,
        Peri<'static, DAC3>,
        Peri<'static, DAC4>,
    ),
    _opamps: (Peri<'static, OPAMP3>, Peri<'static, OPAMP4>),
    pins: (
        Peri<'static, PA4>,
        Peri<'static, PA6>,
        Peri<'static, PB1>,
        Peri<'static, PB12>,
    ),
) {
    analog(Flex::new(pins.0));
    analog(Flex::new(pins.1));
    analog(Flex::new(pins.2));
    analog(Flex::new(pins.3));
    clock_analog();
    start_dacs(&[
        (pac::DAC1, 0, DacMode::NORMAL_EXT_BUFEN),
        (pac::DAC2, 0, DacMode::NORMAL_EXT_BUFEN),
        (pac::DAC3, 1, DacMode::NORMAL_INT_BUFDIS),
        (pac::DAC4, 0, DacMode::NORMAL_INT_BUFDIS),
    ]);
    start_followers(&[pac::OPAMP3, pac::OPAMP4]);
}

/// A STEP output: timer `tim` channel `C` on `pin`, whose repetition counter holds
/// `rep_capacity` periods. `AdvancedInstance4Channel` admits exactly the timers with a
/// repetition counter and break/dead-time register (TIM1/8/20, TIM15/16/17).
fn step_timer<T: AdvancedInstance4Channel, C: TimerChannel>(
    tim: Peri<'static, T>,
    pin: Peri<'static, impl TimerPin<T, C>>,
    rep_capacity: u32,
) -> Option<StepOutput> {
    let clock = claim_timer(tim);
    // SAFETY: TIM1/8/20 and TIM15/16/17 share the advanced-timer register layout for
    // every register StepTimer touches (embassy's own drivers view timers through the
    // widest block the same way), and the timer is ours alone.
    let regs = unsafe { pac::timer::TimAdv::from_ptr(T::regs()) };
    let timer = StepTimer::new(regs, C::CHANNEL.index(), rep_capacity, clock.0);
    // Only now, with the channel idle low, hand the pin to the timer.
    core::mem::forget(PwmPin::<T, C>::new(pin, OutputType::PushPull));
    Some(StepOutput::Tim(timer))
}

/// The STEP output of stepper channel 6: HRTIM1 timer A output 2 on PA9. HRTIM1 is
/// clocked by the APB2 timer clock (stm32-data: `PCLK2_TIM`, 170 MHz here). `None`,
/// with PA9 held low, if the HRTIM's DLL does not calibrate.
fn hrtim_step(
    _hrtim: Peri<'static, HRTIM1>,
    pin: Peri<'static, PA9>,
    rcc: &Peri<'static, RCC>,
) -> Option<StepOutput> {
    embassy_stm32::rcc::enable_and_reset::<HRTIM1>();
    let clock = defmt::unwrap!(embassy_stm32::rcc::clocks(rcc).pclk2_tim.to_hertz());
    let Some(timer) = HrStepTimer::new(pac::HRTIM1, clock.0) else {
        defmt::warn!("HRTIM1 DLL not ready: stepper channel 6 is not driven");
        // Forgotten, the output keeps driving PA9 low for good.
        core::mem::forget(Output::new(pin, Level::Low, Speed::Low));
        return None;
    };
    // Only now, with the output in RUN state and inactive, hand the pin to the HRTIM.
    hrtim_cha2_pin(pin);
    Some(StepOutput::Hrtim(timer))
}
