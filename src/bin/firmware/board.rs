//! The NUCLEO-G474RE board: the only file that names pins, timers, DMA or interrupts.
//!
//! Everything hardware-specific lives here: the clock tree, the complete pin map (as
//! typed embassy pins, so a pin without the named alternate function does not compile),
//! the timers the firmware programs directly through the PAC, and the interrupt
//! handlers and priorities. The rest of the firmware receives ready-made handles from
//! [`init`]. `docs/wiring.md` is the same map as a wiring table; keep them in step.
//!
//! Invariants: the STM32G474RE in LQFP64 has 38 GPIOs left once SWD (PA13/PA14), the
//! ST-LINK virtual COM port (PA2/PA3), the HSE and LSE crystals (PF0/PF1, PC14/PC15),
//! BOOT0 (PB8), the user button (PC13), the LED (PA5) and USB (PA11/PA12) are set
//! aside, and this map uses all 38. Timer use: TIM1, TIM8, TIM20, TIM15, TIM16, TIM17
//! STEP trains (stepper channels 0-5); HRTIM1 reserved for stepper channel 6; TIM2,
//! TIM3, TIM4, TIM5 encoders; TIM7 the 1 kHz interpolation tick; TIM6 the embassy time
//! base. Alternate functions were checked against stm32-metapac 21 (stm32-data) for
//! the STM32G474RE; connector positions follow the NUCLEO-G474RE user manual (UM2505).

use embassy_stm32::flash::{Blocking, Flash};
use embassy_stm32::gpio::{AnyPin, Input, Level, Output, OutputType, Pull, Speed};
use embassy_stm32::interrupt;
use embassy_stm32::interrupt::{InterruptExt, Priority};
use embassy_stm32::pac;
use embassy_stm32::peripherals::{
    self, DAC1, DAC2, DAC3, DAC4, OPAMP3, OPAMP4, PA4, PA6, PB1, PB12,
};
use embassy_stm32::time::Hertz;
use embassy_stm32::timer::low_level::Timer as LowLevelTimer;
use embassy_stm32::timer::qei::{self, Qei};
use embassy_stm32::timer::simple_pwm::PwmPin;
use embassy_stm32::timer::{
    AdvancedInstance4Channel, Ch1, Ch2, Ch3, Ch4, GeneralInstance4Channel, TimerChannel, TimerPin,
};
use embassy_stm32::usb::{self, Driver};
use embassy_stm32::{bind_interrupts, Config, Peri, Peripherals};
use pkmc::units::TICK_HZ;

use crate::encoders::Encoders;
use crate::steppers::{StepChannel, StepTimer, Steppers, REP_ADVANCED, REP_COMPACT};

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
/// Level of a limit input while its switch is open (limit reached): NC switches to GND
/// with pull-ups, min and max switches of a joint in series.
pub const LIMIT_ACTIVE: Level = Level::High;
/// Level of the shared servo-fault input while an amplifier reports a fault:
/// open-collector fault outputs, wired together, pulled up on the board.
pub const SERVO_FAULT_ACTIVE: Level = Level::Low;
/// Level that enables the stepper drives on STEP_EN (buffered to every drive's ENABLE).
pub const STEPPER_ENABLE_ACTIVE: Level = Level::High;
/// Level that enables the servo amplifiers on SERVO_EN.
pub const SERVO_ENABLE_ACTIVE: Level = Level::High;

bind_interrupts!(
    /// Interrupts bound to embassy drivers.
    pub struct Irqs {
        USB_LP => usb::InterruptHandler<peripherals::USB>;
    }
);

/// The USB driver type.
pub type UsbDriver = Driver<'static, peripherals::USB>;

/// The 1 kHz interpolation tick timer (basic timer TIM7, IRQ `TIM7_DAC`).
const TICK_TIMER: pac::timer::TimBasic = pac::TIM7;
/// The embassy time base (basic timer TIM6, IRQ `TIM6_DAC`), read by
/// [`crate::time_driver`].
pub const TIME_BASE: pac::timer::TimBasic = pac::TIM6;
/// Counting rate of both basic timers, Hz.
pub const BASIC_TIMER_COUNT_HZ: u32 = 1_000_000;

/// Clock tree: HSE 24 MHz crystal (X3) → PLL (÷6 × 85 ÷ 2) → 170 MHz SYSCLK in range-1
/// boost mode; AHB, APB1 and APB2 undivided (timer kernels at 170 MHz); USB from
/// HSI48 trimmed by the CRS on USB start-of-frame.
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
    config
}

/// Inputs and outputs watched or held by the heartbeat task, not by the tick.
pub struct Panel {
    /// Limit inputs of stepper channels 0..6 (min and max in series), then one shared
    /// by all servo channels.
    pub limits: [Input<'static>; 8],
    /// Shared servo amplifier fault input.
    pub servo_fault: Input<'static>,
    /// Servo amplifier enable, held inactive: the servo output path is not written yet.
    _servo_enable: Output<'static>,
    /// The analog command pins and their converters, reserved for the servo outputs.
    _servo_analog: ServoAnalog,
}

/// Reserved servo command outputs: DAC1_OUT1 on PA4, DAC2_OUT1 on PA6, DAC3_CH2
/// through OPAMP3 (follower) on PB1, DAC4_CH1 through OPAMP4 (follower) on PB12. Held,
/// not configured: the pins stay in their reset (analog, high-impedance) state.
pub struct ServoAnalog {
    _dacs: (
        Peri<'static, DAC1>,
        Peri<'static, DAC2>,
        Peri<'static, DAC3>,
        Peri<'static, DAC4>,
    ),
    _opamps: (Peri<'static, OPAMP3>, Peri<'static, OPAMP4>),
    _pins: (
        Peri<'static, PA4>,
        Peri<'static, PA6>,
        Peri<'static, PB1>,
        Peri<'static, PB12>,
    ),
}

/// The 1 kHz tick timer, configured and waiting for [`TickTimer::start`].
pub struct TickTimer {
    _private: (),
}

impl TickTimer {
    /// Starts the interpolation tick: from now on `TIM7_DAC` fires every
    /// 1 / [`TICK_HZ`] s at priority 1 (above USB and the time base).
    pub fn start(self) {
        TICK_TIMER.cr1().modify(|w| w.set_cen(true));
        interrupt::TIM7_DAC.set_priority(Priority::P1);
        // SAFETY: the handler below only takes critical sections; no priority-based
        // locking relies on this interrupt staying masked.
        unsafe { interrupt::TIM7_DAC.enable() };
    }
}

/// Everything [`init`] hands to the rest of the firmware.
pub struct Board {
    /// USB full-speed device on PA11 (D−) / PA12 (D+).
    pub usb: UsbDriver,
    /// Green user LED LD2 (PA5), active high.
    pub led: Output<'static>,
    /// STEP/DIR channels and the shared stepper ENABLE.
    pub steppers: Steppers,
    /// Quadrature encoder counters of the servo channels.
    pub encoders: Encoders,
    /// E-stop input (PA10), see [`ESTOP_ACTIVE`].
    pub estop: Input<'static>,
    /// Limits, fault and the held servo outputs.
    pub panel: Panel,
    /// The interpolation tick, ready to start.
    pub tick: TickTimer,
    /// The flash, for the machine-configuration page ([`CONFIG_PAGE_OFFSET`]).
    pub flash: Flash<'static, Blocking>,
}

/// Offset (from the start of flash) of the page that keeps the machine configuration:
/// the last 4 KB page of the 512 KB single-bank flash; `memory.x` ends the program
/// region before it.
pub const CONFIG_PAGE_OFFSET: u32 = 508 * 1024;
/// Size of that page (single-bank mode erases 4 KB pages).
pub const CONFIG_PAGE_BYTES: u32 = 4 * 1024;

/// Sets up every pin and timer of the pin map and the embassy time base.
///
/// Call once, right after `embassy_stm32::init`, before anything uses embassy-time.
pub fn init(p: Peripherals) -> Board {
    start_time_base(p.TIM6);
    let tick = configure_tick(p.TIM7);

    // Stepper channels: STEP on a timer channel, DIR a GPIO (low = reverse).
    let dir = |pin: Peri<'static, AnyPin>| Output::new(pin, Level::Low, Speed::Low);
    let channels = [
        // 0: TIM1_CH1 on PA8 (AF6).
        StepChannel::new(
            Some(step_timer::<_, Ch1>(p.TIM1, p.PA8, REP_ADVANCED)),
            dir(p.PC0.into()),
        ),
        // 1: TIM8_CH4 on PC9 (AF4).
        StepChannel::new(
            Some(step_timer::<_, Ch4>(p.TIM8, p.PC9, REP_ADVANCED)),
            dir(p.PC1.into()),
        ),
        // 2: TIM20_CH3 on PC8 (AF6).
        StepChannel::new(
            Some(step_timer::<_, Ch3>(p.TIM20, p.PC8, REP_ADVANCED)),
            dir(p.PC2.into()),
        ),
        // 3: TIM15_CH1 on PB14 (AF1).
        StepChannel::new(
            Some(step_timer::<_, Ch1>(p.TIM15, p.PB14, REP_COMPACT)),
            dir(p.PC3.into()),
        ),
        // 4: TIM16_CH1 on PB4 (AF1).
        StepChannel::new(
            Some(step_timer::<_, Ch1>(p.TIM16, p.PB4, REP_COMPACT)),
            dir(p.PC4.into()),
        ),
        // 5: TIM17_CH1 on PA7 (AF1).
        StepChannel::new(
            Some(step_timer::<_, Ch1>(p.TIM17, p.PA7, REP_COMPACT)),
            dir(p.PC5.into()),
        ),
        // 6: reserved for HRTIM1 timer A output 2 on PA9 (AF13); driven low for now.
        StepChannel::new(None, dir(p.PB13.into())),
    ];
    let reserved_step = Output::new(p.PA9, Level::Low, Speed::Low);
    let enable = Output::new(p.PB15, opposite(STEPPER_ENABLE_ACTIVE), Speed::Low);
    let steppers = Steppers::new(channels, enable, STEPPER_ENABLE_ACTIVE, reserved_step);

    let encoders = Encoders::new([
        encoder(p.TIM2, p.PA0, p.PA1),  // servo 0: TIM2 CH1/CH2, AF1
        encoder(p.TIM3, p.PC6, p.PC7),  // servo 1: TIM3 CH1/CH2, AF2
        encoder(p.TIM4, p.PB6, p.PB7),  // servo 2: TIM4 CH1/CH2, AF2
        encoder(p.TIM5, p.PB2, p.PC12), // servo 3: TIM5 CH1 AF2 / CH2 AF1
    ]);

    let input = |pin: Peri<'static, AnyPin>| Input::new(pin, Pull::Up);
    let panel = Panel {
        limits: [
            input(p.PC10.into()),
            input(p.PC11.into()),
            input(p.PD2.into()),
            input(p.PA15.into()),
            input(p.PB0.into()),
            input(p.PB9.into()),
            input(p.PB10.into()),
            input(p.PB3.into()),
        ],
        servo_fault: Input::new(p.PB11, Pull::Up),
        _servo_enable: Output::new(p.PB5, opposite(SERVO_ENABLE_ACTIVE), Speed::Low),
        _servo_analog: ServoAnalog {
            _dacs: (p.DAC1, p.DAC2, p.DAC3, p.DAC4),
            _opamps: (p.OPAMP3, p.OPAMP4),
            _pins: (p.PA4, p.PA6, p.PB1, p.PB12),
        },
    };

    let usb = Driver::new(p.USB, Irqs, p.PA12, p.PA11);
    interrupt::USB_LP.set_priority(Priority::P2);

    Board {
        flash: Flash::new_blocking(p.FLASH),
        usb,
        led: Output::new(p.PA5, Level::Low, Speed::Low),
        steppers,
        encoders,
        estop: Input::new(p.PA10, Pull::Up),
        panel,
        tick,
    }
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

/// A STEP output: timer `tim` channel `C` on `pin`, whose repetition counter holds
/// `rep_capacity` periods. `AdvancedInstance4Channel` admits exactly the timers with a
/// repetition counter and break/dead-time register (TIM1/8/20, TIM15/16/17).
fn step_timer<T: AdvancedInstance4Channel, C: TimerChannel>(
    tim: Peri<'static, T>,
    pin: Peri<'static, impl TimerPin<T, C>>,
    rep_capacity: u32,
) -> StepTimer {
    let clock = claim_timer(tim);
    // SAFETY: TIM1/8/20 and TIM15/16/17 share the advanced-timer register layout for
    // every register StepTimer touches (embassy's own drivers view timers through the
    // widest block the same way), and the timer is ours alone.
    let regs = unsafe { pac::timer::TimAdv::from_ptr(T::regs()) };
    let timer = StepTimer::new(regs, C::CHANNEL.index(), rep_capacity, clock.0);
    // Only now, with the channel idle low, hand the pin to the timer.
    core::mem::forget(PwmPin::<T, C>::new(pin, OutputType::PushPull));
    timer
}

/// A quadrature encoder on timer `tim` (CH1 = A, CH2 = B), counting all four edges.
fn encoder<T: GeneralInstance4Channel>(
    tim: Peri<'static, T>,
    a: Peri<'static, impl TimerPin<T, Ch1>>,
    b: Peri<'static, impl TimerPin<T, Ch2>>,
) -> pac::timer::TimGp16 {
    let qei = Qei::new(tim, a, b, qei::Config::default());
    // Dropping the driver would stop the timer's clock and float the pins.
    core::mem::forget(qei);
    // SAFETY: every encoder timer has at least the general-purpose 16-bit layout; the
    // firmware only reads its counter.
    unsafe { pac::timer::TimGp16::from_ptr(T::regs()) }
}

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

/// Prepares TIM7 as the interpolation tick, stopped.
fn configure_tick(tim: Peri<'static, peripherals::TIM7>) -> TickTimer {
    let timer = LowLevelTimer::new(tim);
    let clock = timer.get_clock_frequency();
    core::mem::forget(timer);
    configure_basic(TICK_TIMER, clock, TICK_HZ, false);
    TickTimer { _private: () }
}

/// The interpolation tick interrupt.
#[interrupt]
fn TIM7_DAC() {
    TICK_TIMER.sr().write(|w| w.set_uif(false));
    crate::on_tick();
}

/// The embassy time-base interrupt.
#[interrupt]
fn TIM6_DAC() {
    crate::time_driver::on_overflow();
}
