//! The NUCLEO-G474RE board: the only file that names pins, timers, DMA or interrupts.
//!
//! Everything hardware-specific lives here: the clock tree, the complete pin map (as
//! typed embassy pins, so a pin without the named alternate function does not compile),
//! the timers, converters and watchdog the firmware programs directly through the PAC,
//! and the interrupt handlers and priorities. The rest of the firmware receives
//! ready-made handles from [`init`]. `docs/wiring.md` is the same map as a wiring
//! table; keep them in step.
//!
//! Invariants: the STM32G474RE in LQFP64 has 38 GPIOs left once SWD (PA13/PA14), the
//! ST-LINK virtual COM port (PA2/PA3), the HSE and LSE crystals (PF0/PF1, PC14/PC15),
//! BOOT0 (PB8), the user button (PC13), the LED (PA5) and USB (PA11/PA12) are set
//! aside, and this map uses all 38. Timer use: TIM1, TIM8, TIM20, TIM15, TIM16, TIM17
//! STEP trains (stepper channels 0-5); HRTIM1 timer A the STEP train of stepper channel
//! 6; TIM2, TIM3, TIM4, TIM5 encoders; TIM7 the 10 kHz servo period, which also paces
//! the 1 kHz interpolation tick (run on the otherwise unused `UCPD1` vector); TIM6 the
//! embassy time base; the IWDG watches both interrupts. Alternate functions were checked
//! against stm32-metapac 21 (stm32-data) for the STM32G474RE; connector positions
//! follow the NUCLEO-G474RE user manual (UM2505). One pin is not typed by its
//! function: PA9 (HRTIM1_CHA2, AF13), because embassy-stm32's HRTIM pin traits come
//! with its `stm32-hrtim` feature, which this build does not enable; the pin is fixed
//! by type and its AF number by [`HRTIM1_CHA2_AF`].
//!
//! Interrupt priorities (lower number = more urgent):
//!
//! | priority | interrupt | work |
//! |---|---|---|
//! | 0 | `TIM7_DAC` | servo period, 10 kHz: encoders, loops, DACs; pends the tick every 10th |
//! | 1 | `UCPD1` (software) | interpolation tick, 1 kHz: step trains, switches, controller |
//! | 2 | `USB_LP` | USB device |
//! | 3 | `TIM6_DAC` | embassy time base |
//!
//! Why a software-pended tick rather than a second timer: no timer is free (see above),
//! and pending the tick from the servo interrupt makes it run exactly every
//! [`pkmc::servo::SERVO_PER_TICK`]th servo period, so the servo loops load each tick's
//! targets at a fixed phase. The servo interrupt is the most urgent so that the tick
//! (tens to hundreds of µs of planning and kinematics) never delays a servo period;
//! the controller and the tick's data are shared with thread-mode tasks under a
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
use embassy_stm32::flash::{Blocking, Flash};
use embassy_stm32::gpio::{AfType, AnyPin, Flex, Input, Level, Output, OutputType, Pull, Speed};
use embassy_stm32::interrupt;
use embassy_stm32::interrupt::{InterruptExt, Priority};
use embassy_stm32::pac;
use embassy_stm32::pac::dac::vals::Mode as DacMode;
use embassy_stm32::pac::iwdg::vals::{Key, Pr};
use embassy_stm32::pac::opamp::vals::{VmSel, VpSel};
use embassy_stm32::peripherals::{
    self, DAC1, DAC2, DAC3, DAC4, HRTIM1, OPAMP3, OPAMP4, PA4, PA6, PA9, PB1, PB12, RCC,
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
use pkmc::config::{BOARD_STEPS_PER_TICK, MAX_SERVOS};
use pkmc::servo::{DAC_MID, SERVO_HZ};

use crate::encoders::Encoders;
use crate::steppers::{periods, HrStepTimer, StepChannel, StepOutput, StepTimer, Steppers};

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

/// The servo-period timer (basic timer TIM7, IRQ `TIM7_DAC`), at [`SERVO_HZ`].
const SERVO_TIMER: pac::timer::TimBasic = pac::TIM7;

/// Priority of the servo-period interrupt: the most urgent.
const SERVO_PRIORITY: Priority = Priority::P0;
/// Priority of the interpolation tick; also the ceiling of [`crate::shared::TickShared`].
pub const TICK_PRIORITY: Priority = Priority::P1;
/// The tick's interrupt: the NVIC line of the USB Type-C/PD controller UCPD1, which the
/// board does not use (its CC pins PB4/PB6 are STEP4 and ENC2 A), pended by software.
const TICK_IRQ: interrupt::Interrupt = interrupt::UCPD1;
const _: () = assert!((SERVO_PRIORITY as u8) < (TICK_PRIORITY as u8));

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

/// The switch inputs, sampled by the tick.
pub struct Switches {
    /// E-stop input (PA10), see [`ESTOP_ACTIVE`].
    estop: Input<'static>,
    /// Limit/home inputs 0..8: input k is joint k's shared home/limit switch.
    limits: [Input<'static>; 8],
}

impl Switches {
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

/// The servo channels' hardware, driven by the servo interrupt: encoders, analog
/// command outputs, the shared amplifier enable and the shared fault input.
pub struct ServoIo {
    /// Quadrature encoder counters of the servo channels.
    pub encoders: Encoders,
    /// DAC of each servo channel and its channel index: DAC1 ch1 (PA4), DAC2 ch1
    /// (PA6), DAC3 ch2 (→ OPAMP3 → PB1), DAC4 ch1 (→ OPAMP4 → PB12).
    dacs: [(pac::dac::Dac, usize); MAX_SERVOS],
    /// SERVO_EN (PB5): enables every amplifier.
    enable: Output<'static>,
    /// SERVO_FAULT (PB11): open-collector fault outputs of every amplifier, wired
    /// together.
    fault: Input<'static>,
}

impl ServoIo {
    /// The raw shared fault input: true = some amplifier reports a fault.
    pub fn fault(&self) -> bool {
        self.fault.get_level() == SERVO_FAULT_ACTIVE
    }

    /// Writes the DAC codes (12-bit, right-aligned; the DACs convert at once, no
    /// trigger) and the shared enable: the enable goes off before new codes and on
    /// after them.
    pub fn write(&mut self, codes: &[u16; MAX_SERVOS], enable: bool) {
        if !enable {
            self.enable.set_level(opposite(SERVO_ENABLE_ACTIVE));
        }
        for ((dac, channel), &code) in self.dacs.iter().zip(codes) {
            dac.dhr12r(*channel).write(|w| w.set_dhr(code));
        }
        if enable {
            self.enable.set_level(SERVO_ENABLE_ACTIVE);
        }
    }
}

/// The servo-period timer, configured and waiting for [`ServoTimer::start`].
pub struct ServoTimer {
    _private: (),
}

impl ServoTimer {
    /// Starts the servo period: from now on `TIM7_DAC` fires every 1 / [`SERVO_HZ`] s at
    /// priority 0 and the tick can be pended on its vector at priority 1.
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
        SERVO_TIMER.cr1().modify(|w| w.set_cen(true));
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
    /// Green user LED LD2 (PA5), active high.
    pub led: Output<'static>,
    /// STEP/DIR channels and the shared stepper ENABLE.
    pub steppers: Steppers,
    /// E-stop and limit/home inputs.
    pub switches: Switches,
    /// Encoders, analog outputs, enable and fault of the servo channels.
    pub servo: ServoIo,
    /// The servo period (and with it the tick), ready to start.
    pub timer: ServoTimer,
    /// The flash, for the machine-configuration page ([`CONFIG_PAGE_OFFSET`]).
    pub flash: Flash<'static, Blocking>,
}

/// Offset (from the start of flash) of the page that keeps the machine configuration:
/// the last 4 KB of the 512 KB flash, bank 2's last two 2 KB pages (dual-bank mode,
/// the factory setting, see `memory.x`); `memory.x` ends the program region before it.
pub const CONFIG_PAGE_OFFSET: u32 = 508 * 1024;
/// Size of that region (two 2 KB pages, erased together).
pub const CONFIG_PAGE_BYTES: u32 = 4 * 1024;

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
/// The watchdog runs from here on: start the servo timer within [`WATCHDOG_MS`].
pub fn init(p: Peripherals) -> Board {
    start_watchdog();
    start_time_base(p.TIM6);
    let timer = configure_servo_timer(p.TIM7);

    // Stepper channels: STEP on a timer channel, DIR a GPIO (low = reverse).
    let dir = |pin: Peri<'static, AnyPin>| Output::new(pin, Level::Low, Speed::Low);
    let channels = [
        // 0: TIM1_CH1 on PA8 (AF6).
        StepChannel::new(
            step_timer::<_, Ch1>(p.TIM1, p.PA8, steps_per_tick!(0, pac::TIM1.rcr())),
            dir(p.PC0.into()),
        ),
        // 1: TIM8_CH4 on PC9 (AF4).
        StepChannel::new(
            step_timer::<_, Ch4>(p.TIM8, p.PC9, steps_per_tick!(1, pac::TIM8.rcr())),
            dir(p.PC1.into()),
        ),
        // 2: TIM20_CH3 on PC8 (AF6).
        StepChannel::new(
            step_timer::<_, Ch3>(p.TIM20, p.PC8, steps_per_tick!(2, pac::TIM20.rcr())),
            dir(p.PC2.into()),
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
        encoder(p.TIM2, p.PA0, p.PA1),  // servo 0: TIM2 CH1/CH2, AF1
        encoder(p.TIM3, p.PC6, p.PC7),  // servo 1: TIM3 CH1/CH2, AF2
        encoder(p.TIM4, p.PB6, p.PB7),  // servo 2: TIM4 CH1/CH2, AF2
        encoder(p.TIM5, p.PB2, p.PC12), // servo 3: TIM5 CH1 AF2 / CH2 AF1
    ]);
    // Amplifiers disabled before their command outputs come up (at zero command).
    let servo_enable = Output::new(p.PB5, opposite(SERVO_ENABLE_ACTIVE), Speed::Low);
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
        enable: servo_enable,
        fault: Input::new(p.PB11, Pull::Up),
    };

    let input = |pin: Peri<'static, AnyPin>| Input::new(pin, Pull::Up);
    let switches = Switches {
        estop: Input::new(p.PA10, Pull::Up),
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
    };

    let usb = Driver::new(p.USB, Irqs, p.PA12, p.PA11);
    interrupt::USB_LP.set_priority(Priority::P2);

    Board {
        flash: Flash::new_blocking(p.FLASH),
        usb,
        led: Output::new(p.PA5, Level::Low, Speed::Low),
        steppers,
        switches,
        servo,
        timer,
    }
}

/// DAC_MCR.HFSEL for the 170 MHz AHB clock of [`clock_config`]: 0b10, "AHB clock
/// above 160 MHz" (RM0440, DAC mode control register).
const DAC_HFSEL: u8 = 0b10;
/// Polls of DAC_SR.DACRDY before giving up waiting: far beyond the DAC's wake-up time
/// (a few µs; one poll is at least a few cycles at 170 MHz).
const DAC_READY_POLLS: u32 = 10_000;

/// Brings up the four analog command outputs at mid-scale (zero command):
/// DAC1 ch1 → PA4 and DAC2 ch1 → PA6 through the DACs' own output buffers; DAC3 ch2
/// and DAC4 ch1 (internal-only converters, unbuffered) into OPAMP3 and OPAMP4 as
/// voltage followers (VINP = their DAC, VINM = their output) driving PB1 and PB12.
/// Register level: the servo interrupt then writes one data register per channel.
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
    // Analog mode (their reset state, made explicit); the pins stay ours for good.
    fn analog(mut pin: Flex<'static>) {
        pin.set_as_analog();
        core::mem::forget(pin);
    }
    analog(Flex::new(pins.0));
    analog(Flex::new(pins.1));
    analog(Flex::new(pins.2));
    analog(Flex::new(pins.3));

    pac::RCC.ahb2enr().modify(|w| {
        w.set_dac1en(true);
        w.set_dac2en(true);
        w.set_dac3en(true);
        w.set_dac4en(true);
    });
    // The OPAMP registers are clocked with SYSCFG (RCC_APB2ENR.SYSCFGEN).
    pac::RCC.apb2enr().modify(|w| w.set_syscfgen(true));
    // Read back: the clocks are on before the first register access.
    let _ = pac::RCC.ahb2enr().read();
    let _ = pac::RCC.apb2enr().read();

    let channels = [
        (pac::DAC1, 0, DacMode::NORMAL_EXT_BUFEN),
        (pac::DAC2, 0, DacMode::NORMAL_EXT_BUFEN),
        (pac::DAC3, 1, DacMode::NORMAL_INT_BUFDIS),
        (pac::DAC4, 0, DacMode::NORMAL_INT_BUFDIS),
    ];
    for (dac, ch, mode) in channels {
        // Mode and HFSEL are written with the channel disabled; data before enabling,
        // so the output comes up at mid-scale. No trigger: DHR → DOR at once.
        dac.mcr().modify(|w| {
            w.set_hfsel(DAC_HFSEL);
            w.set_mode(ch, mode);
        });
        dac.dhr12r(ch).write(|w| w.set_dhr(DAC_MID as u16));
        dac.cr().modify(|w| w.set_en(ch, true));
    }
    for (dac, ch, _) in channels {
        let mut polls = 0;
        while !dac.sr().read().dacrdy(ch) && polls < DAC_READY_POLLS {
            polls += 1;
        }
        // Again, now that the channel is on, in case the write to a disabled channel
        // did not reach its output register.
        dac.dhr12r(ch).write(|w| w.set_dhr(DAC_MID as u16));
    }
    for opamp in [pac::OPAMP3, pac::OPAMP4] {
        opamp.csr().write(|w| {
            // VINP3: OPAMP3's is DAC3_CH2, OPAMP4's DAC4_CH1 (the PAC names the value
            // after OPAMP1's, DAC3_CH1).
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

/// Alternate function of HRTIM1_CHA2 on PA9 (stm32-metapac 21, STM32G474RE).
pub const HRTIM1_CHA2_AF: u8 = 13;

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
    let mut pin = Flex::new(pin);
    pin.set_as_af_unchecked(
        HRTIM1_CHA2_AF,
        AfType::output(OutputType::PushPull, Speed::VeryHigh),
    );
    // Dropping the pin would disconnect it.
    core::mem::forget(pin);
    Some(StepOutput::Hrtim(timer))
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
