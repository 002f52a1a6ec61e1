//! The board's wiring to the machine: which pin carries which drive signal, as
//! `docs/wiring.md` tables them (the PCB between the NUCLEO and the drives). This is
//! the board's side, written from the wiring document, not from the firmware: a
//! firmware that drove another pin, or the right pin with the wrong alternate
//! function, would move nothing.
//!
//! Alternate-function numbers are the STM32G474 datasheet's (DS12288, "Alternate
//! function" tables), as `docs/wiring.md` lists them.

/// A pin: port letter index (0 = A) and number.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Pin {
    /// Port index: 0 = A, 1 = B, …
    pub port: usize,
    /// Pin number 0–15.
    pub pin: usize,
}

const fn p(port: char, pin: usize) -> Pin {
    Pin {
        port: port as usize - 'A' as usize,
        pin,
    }
}

/// Where a STEP signal comes from.
#[derive(Clone, Copy, Debug)]
pub enum StepSource {
    /// A timer channel (timer name, 0-based channel) on `pin` with alternate function
    /// `af`.
    Timer(&'static str, usize, Pin, u32),
    /// HRTIM1 timer A output 2 on `pin` with alternate function `af`.
    Hrtim(Pin, u32),
}

/// Where an encoder's A and B go.
#[derive(Clone, Copy, Debug)]
pub enum EncoderSink {
    /// A timer's CH1/CH2 inputs on pins A and B with their alternate functions.
    Timer(&'static str, (Pin, u32), (Pin, u32)),
    /// A timer's CH1 on pin A; B into comparator `comp` (0-based) on its analog pin,
    /// whose output the timer selects as TI2 (TIMx_TISEL).
    TimerComp(&'static str, (Pin, u32), usize, Pin),
    /// LPTIM1's IN1 and IN2 on pins A and B with their alternate functions.
    Lptim((Pin, u32), (Pin, u32)),
}

/// Where a servo command comes from.
#[derive(Clone, Copy, Debug)]
pub enum CommandSource {
    /// DAC `dac` (0-based) channel `ch` on its own buffered pin.
    Dac(usize, usize, Pin),
    /// DAC `dac` channel `ch` through OPAMP `opamp` (0-based) as follower to `pin`.
    Follower(usize, usize, usize, Pin),
    /// HRTIM1 timer A output 2 on `pin` (alternate function `af`), PWM filtered by
    /// the board's RC low-pass: the command is the duty (CMP1 / PER, set at the period
    /// and reset at CMP1), scaled to the DACs' 4096 codes.
    HrtimPwm(Pin, u32),
}

/// The touch probe's input: a timer's capture input on a pin.
#[derive(Clone, Copy, Debug)]
pub struct ProbeInput {
    /// The pin (high = touching).
    pub pin: Pin,
    /// The timer.
    pub timer: &'static str,
    /// Its capture input TIx, 0-based.
    pub input: usize,
    /// The pin's alternate function for it.
    pub af: u32,
}

/// A wiring.
pub struct Wiring {
    /// Name.
    pub name: &'static str,
    /// STEP, DIR of each stepper channel.
    pub steppers: Vec<(StepSource, Pin)>,
    /// Shared stepper ENABLE (high = enabled).
    pub step_enable: Option<Pin>,
    /// Encoder and command of each servo channel.
    pub servos: Vec<(EncoderSink, CommandSource)>,
    /// Amplifier group of each servo channel.
    pub servo_group: Vec<usize>,
    /// Enable output (high = enabled) and fault input (low = fault) of each group.
    pub amp_lines: Vec<(Pin, Pin)>,
    /// E-stop input (high = e-stop).
    pub estop: Pin,
    /// Limit/home inputs (high = switch open: limit or home reached).
    pub limits: Vec<Pin>,
    /// The heartbeat LED, if wired.
    pub led: Option<Pin>,
    /// The touch probe, if wired.
    pub probe: Option<ProbeInput>,
}

/// The default wiring: seven stepper channels, four servo channels
/// (`docs/wiring.md`, "Stepper channels", "Servo channels", "Switches").
pub fn mixed() -> Wiring {
    Wiring {
        name: "default (seven steppers, four servos)",
        steppers: vec![
            (StepSource::Timer("TIM1", 0, p('A', 8), 6), p('A', 0)),
            (StepSource::Timer("TIM8", 3, p('C', 9), 4), p('C', 1)),
            (StepSource::Timer("TIM20", 2, p('C', 8), 6), p('A', 1)),
            (StepSource::Timer("TIM15", 0, p('B', 14), 1), p('C', 3)),
            (StepSource::Timer("TIM16", 0, p('B', 4), 1), p('C', 4)),
            (StepSource::Timer("TIM17", 0, p('A', 7), 1), p('C', 5)),
            (StepSource::Hrtim(p('A', 9), 13), p('B', 13)),
        ],
        step_enable: Some(p('B', 15)),
        servos: vec![
            (
                EncoderSink::Lptim((p('C', 0), 1), (p('C', 2), 1)),
                CommandSource::Dac(0, 0, p('A', 4)),
            ),
            (
                EncoderSink::Timer("TIM3", (p('C', 6), 2), (p('C', 7), 2)),
                CommandSource::Dac(1, 0, p('A', 6)),
            ),
            (
                EncoderSink::Timer("TIM4", (p('B', 6), 2), (p('B', 7), 2)),
                CommandSource::Follower(2, 1, 2, p('B', 1)),
            ),
            (
                EncoderSink::Timer("TIM5", (p('B', 2), 2), (p('C', 12), 1)),
                CommandSource::Follower(3, 0, 3, p('B', 12)),
            ),
        ],
        servo_group: vec![0; 4],
        amp_lines: vec![(p('B', 5), p('B', 11))],
        estop: p('A', 10),
        limits: vec![
            p('C', 10),
            p('C', 11),
            p('D', 2),
            p('A', 15),
            p('B', 0),
            p('B', 9),
            p('B', 10),
            p('B', 3),
        ],
        led: Some(p('A', 5)),
        probe: Some(ProbeInput {
            pin: p('A', 2),
            timer: "TIM2",
            input: 2,
            af: 1,
        }),
    }
}

/// The eight-servo wiring of the hexapod-xy machine (`docs/wiring.md`, "Eight-servo
/// wiring"): six legs and two table axes, no stepper channel.
pub fn servo8() -> Wiring {
    Wiring {
        name: "eight servos",
        steppers: Vec::new(),
        step_enable: None,
        servos: vec![
            (
                EncoderSink::Timer("TIM1", (p('C', 0), 2), (p('C', 1), 2)),
                CommandSource::Dac(0, 0, p('A', 4)),
            ),
            (
                EncoderSink::Timer("TIM2", (p('A', 15), 1), (p('B', 3), 1)),
                CommandSource::Dac(0, 1, p('A', 5)),
            ),
            (
                EncoderSink::Timer("TIM3", (p('B', 4), 2), (p('A', 7), 2)),
                CommandSource::Dac(1, 0, p('A', 6)),
            ),
            (
                EncoderSink::Timer("TIM5", (p('A', 0), 2), (p('A', 1), 2)),
                CommandSource::Follower(2, 1, 2, p('B', 1)),
            ),
            (
                EncoderSink::Timer("TIM8", (p('C', 6), 4), (p('C', 7), 4)),
                CommandSource::Follower(3, 0, 3, p('B', 12)),
            ),
            (
                EncoderSink::Timer("TIM20", (p('B', 2), 3), (p('C', 2), 6)),
                CommandSource::Follower(3, 1, 4, p('A', 8)),
            ),
            (
                EncoderSink::TimerComp("TIM4", (p('B', 6), 2), 3, p('B', 0)),
                CommandSource::Follower(2, 0, 5, p('B', 11)),
            ),
            (
                EncoderSink::Lptim((p('B', 5), 11), (p('B', 7), 11)),
                CommandSource::HrtimPwm(p('A', 9), 13),
            ),
        ],
        servo_group: vec![0, 0, 0, 0, 0, 0, 1, 1],
        amp_lines: vec![(p('B', 15), p('B', 14)), (p('B', 13), p('C', 3))],
        estop: p('A', 10),
        limits: vec![
            p('C', 10),
            p('C', 11),
            p('D', 2),
            p('C', 12),
            p('C', 8),
            p('B', 9),
            p('B', 10),
            p('C', 9),
        ],
        led: Some(p('C', 4)),
        probe: Some(ProbeInput {
            pin: p('A', 2),
            timer: "TIM15",
            input: 0,
            af: 9,
        }),
    }
}
