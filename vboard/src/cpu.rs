//! The Cortex-M4F core: unicorn executes the instructions; this module supplies what
//! unicorn lacks (it has no NVIC): exception entry and return with the basic and the
//! FPU's extended frame, preemption and tail-chaining by priority, BASEPRI and
//! PRIMASK, WFE/WFI with the event register, virtual time from executed instructions,
//! and reset.
//!
//! Source: ARMv7-M Architecture Reference Manual (ARM DDI 0403E), "Exception
//! entry behavior", "Stack alignment on exception entry", "Exception return
//! behavior", "Execution priority", and WFE, WFI and the event register ("Power
//! management"). Lazy FP state preservation ("Lazy context save of FP state"): with
//! FPCCR.LSPEN set (its reset value), an entry from a context with CONTROL.FPCA set
//! reserves the extended frame but writes only R0–R3, R12, LR, PC and xPSR; it sets
//! FPCCR.LSPACT and points FPCAR at the frame's S0 slot. The first floating-point
//! instruction executed while LSPACT is set (in the handler, or in one that preempts
//! it) first writes S0–S15 and FPSCR there and clears LSPACT; an exception return
//! with LSPACT still set clears it and leaves S0–S15 and FPSCR as they are (they were
//! never saved nor changed). The save happens at the start of the translated block
//! holding that instruction: the instructions before it in the block cannot change
//! S0–S15 or FPSCR, so the stored values are those of the instruction's own moment,
//! and an FPCCR read by one of them still sees LSPACT set. (A store by one of them
//! into the reserved slot itself would be overwritten on the core and is not here;
//! code has no business there.)
//! With LSPEN clear, the FP state is stacked at entry.
//!
//! Cycle model: every executed instruction takes one cycle of SYSCLK (counted per
//! translated block, each block's instructions counted once by decoding its Thumb
//! encodings; an IT-skipped instruction counts, as it takes an issue slot). Flash
//! wait states, bus stalls, multi-cycle instructions (divisions, loads/stores of
//! several registers) and the 12-cycle exception entry are not counted: figures of
//! busy time are instruction counts at 170 MHz, a lower bound of the real time.

use crate::board::{Board, Fault};
use crate::elf::Image;
use crate::nvic::IRQ0;
use crate::periph::clocks::ResetCause;
use crate::periph::flash;
use crate::unwind::Unwinder;
use anyhow::{anyhow, bail, Result};
use std::collections::HashMap;
use std::rc::Rc;
use unicorn_engine::unicorn_const::{Arch, HookType, MemType, Mode, Prot};
use unicorn_engine::{RegisterARM, Unicorn};

/// RAM base and size (SRAM1 + SRAM2 + CCM SRAM, contiguous).
pub const RAM: u32 = 0x2000_0000;
/// RAM size.
pub const RAM_SIZE: u32 = 128 * 1024;
/// The CCM SRAM alias at 0x1000_0000 is not used by the firmware: not mapped.
/// Pattern painted over the RAM at power-on (stack depth).
pub const PAINT: u8 = 0xA5;

/// Why [`Core::run`] returned.
pub enum Exit {
    /// The time limit was reached.
    Time,
    /// The board asked to stop (a fault).
    Fault(Fault),
}

/// Per-block instruction counts and whether the block holds a floating-point
/// instruction, by block start address.
#[derive(Default)]
struct Blocks {
    counts: HashMap<u64, (u32, Option<u32>)>,
}

/// Thumb instruction count of `code`, and the offset of its first floating-point
/// instruction if it has one: a 32-bit coprocessor encoding (first half-word 111x 11xx xxxx xxxx)
/// for coprocessor 10 or 11 (bits 11:8 of the second half-word 101x), which covers
/// every VFP data-processing, load/store, register-transfer and VMRS/VMSR encoding
/// (ARMv7-M ARM, "Floating-point instruction encoding").
fn scan_block(code: &[u8]) -> (u32, Option<u32>) {
    let mut n = 0;
    let mut fp = None;
    let mut i = 0;
    while i + 1 < code.len() {
        let hw = u16::from_le_bytes([code[i], code[i + 1]]);
        if matches!(hw >> 11, 0x1D..=0x1F) {
            if let Some(b) = code.get(i + 2..i + 4) {
                let hw2 = u16::from_le_bytes([b[0], b[1]]);
                if fp.is_none() && hw & 0xEC00 == 0xEC00 && hw2 & 0x0E00 == 0x0A00 {
                    fp = Some(i as u32);
                }
            }
            i += 4;
        } else {
            i += 2;
        }
        n += 1;
    }
    (n, fp)
}

/// The core, its memory and the board.
pub struct Core<'a> {
    /// The emulator, owning the board.
    pub uc: Unicorn<'a, Board>,
    /// The firmware image.
    pub image: Rc<Image>,
    flash_image: Vec<u8>,
    sleeping_at: Option<u32>,
    periods_closed: u64,
    /// The core executes nothing until then (its instruction fetch held).
    pub held_until: u64,
    /// The initial main stack pointer (the top of the stack).
    pub stack_top: u32,
}

fn reg(uc: &Unicorn<Board>, r: RegisterARM) -> u32 {
    uc.reg_read(r).unwrap_or(0) as u32
}

fn set(uc: &mut Unicorn<Board>, r: RegisterARM, v: u32) {
    let _ = uc.reg_write(r, u64::from(v));
}

fn read32(uc: &Unicorn<Board>, a: u32) -> u32 {
    let mut b = [0u8; 4];
    let _ = uc.mem_read(u64::from(a), &mut b);
    u32::from_le_bytes(b)
}

fn write32(uc: &mut Unicorn<Board>, a: u32, v: u32) {
    let _ = uc.mem_write(u64::from(a), &v.to_le_bytes());
}

/// R0–R12, SP, LR (an unwind's starting registers, PC apart).
const GPRS: [RegisterARM; 15] = [
    RegisterARM::R0,
    RegisterARM::R1,
    RegisterARM::R2,
    RegisterARM::R3,
    RegisterARM::R4,
    RegisterARM::R5,
    RegisterARM::R6,
    RegisterARM::R7,
    RegisterARM::R8,
    RegisterARM::R9,
    RegisterARM::R10,
    RegisterARM::R11,
    RegisterARM::R12,
    RegisterARM::SP,
    RegisterARM::LR,
];

const FRAME_REGS: [RegisterARM; 6] = [
    RegisterARM::R0,
    RegisterARM::R1,
    RegisterARM::R2,
    RegisterARM::R3,
    RegisterARM::R12,
    RegisterARM::LR,
];

/// Exception entry into `e` ("Exception entry behavior"): stacks the context on the main stack, sets LR
/// to EXC_RETURN, IPSR, and jumps to the vector. `return_pc` is the address to come
/// back to.
fn enter(uc: &mut Unicorn<Board>, e: u32, return_pc: u32) {
    if std::env::var_os("VBOARD_TRACE").is_some() {
        eprintln!(
            "enter {e} from {return_pc:#x} sp {:#x} xpsr {:#x} control {:#x}",
            reg(uc, RegisterARM::SP),
            reg(uc, RegisterARM::XPSR),
            reg(uc, RegisterARM::CONTROL)
        );
    }
    let control = reg(uc, RegisterARM::CONTROL);
    let fp = control & 4 != 0;
    let handler = !uc.get_data().scs.active.is_empty();
    let sp = reg(uc, RegisterARM::SP);
    let size = if fp { 0x68 } else { 0x20 };
    let mut frame = sp.wrapping_sub(size);
    let realign = frame & 4 != 0;
    frame &= !7;
    // The T bit is always set on this Thumb-only core (QEMU may not report it while
    // stopped).
    let mut xpsr = reg(uc, RegisterARM::XPSR) | 1 << 24;
    if realign {
        xpsr |= 1 << 9;
    } else {
        xpsr &= !(1 << 9);
    }
    for (k, r) in FRAME_REGS.iter().enumerate() {
        let v = reg(uc, *r);
        write32(uc, frame + 4 * k as u32, v);
    }
    write32(uc, frame + 24, return_pc);
    write32(uc, frame + 28, xpsr);
    if fp {
        let scs = &mut uc.get_data_mut().scs;
        if scs.fpccr & FPCCR_LSPEN != 0 {
            // Deferred: LSPACT, FPCAR, and who the frame belongs to (privileged
            // always here; THREAD if taken from Thread mode; HardFault may pend).
            scs.fpcar = frame + 32;
            scs.fpccr = (scs.fpccr & !FPCCR_STATE)
                | FPCCR_LSPACT
                | FPCCR_HFRDY
                | if handler { 0 } else { FPCCR_THREAD };
        } else {
            save_fp(uc, frame + 32);
        }
    }
    set(uc, RegisterARM::SP, frame);
    let exc_return = match (handler, fp) {
        (true, false) => 0xFFFF_FFF1,
        (false, false) => 0xFFFF_FFF9,
        (true, true) => 0xFFFF_FFE1,
        (false, true) => 0xFFFF_FFE9,
    };
    set(uc, RegisterARM::LR, exc_return);
    jump_to_handler(uc, e);
    if fp {
        set(uc, RegisterARM::CONTROL, control & !4);
    }
}

/// FPCCR.LSPEN: lazy stacking enabled.
const FPCCR_LSPEN: u32 = 1 << 30;
/// FPCCR.LSPACT: a deferred save is pending.
const FPCCR_LSPACT: u32 = 1;
/// FPCCR.THREAD: the deferred frame was stacked from Thread mode.
const FPCCR_THREAD: u32 = 1 << 3;
/// FPCCR.HFRDY: HardFault could be pended when the save was deferred.
const FPCCR_HFRDY: u32 = 1 << 4;
/// The state bits of FPCCR the core sets at a deferred entry: LSPACT, USER,
/// THREAD, HFRDY, MMRDY, BFRDY, MONRDY.
const FPCCR_STATE: u32 = 0x17B;

/// Writes S0–S15 and FPSCR to the frame slot at `at`.
fn save_fp(uc: &mut Unicorn<Board>, at: u32) {
    for k in 0..16u32 {
        let s = reg(uc, s_reg(k));
        write32(uc, at + 4 * k, s);
    }
    let fpscr = reg(uc, RegisterARM::FPSCR);
    write32(uc, at + 64, fpscr);
}

/// The deferred save, before a floating-point instruction runs while FPCCR.LSPACT
/// is set: the registers go to FPCAR's slot, LSPACT clears.
fn lazy_save(uc: &mut Unicorn<Board>) {
    let at = uc.get_data().scs.fpcar;
    save_fp(uc, at);
    let b = uc.get_data_mut();
    b.scs.fpccr &= !FPCCR_LSPACT;
    b.stats.lazy_saves += 1;
}

fn s_reg(k: u32) -> RegisterARM {
    const S: [RegisterARM; 16] = [
        RegisterARM::S0,
        RegisterARM::S1,
        RegisterARM::S2,
        RegisterARM::S3,
        RegisterARM::S4,
        RegisterARM::S5,
        RegisterARM::S6,
        RegisterARM::S7,
        RegisterARM::S8,
        RegisterARM::S9,
        RegisterARM::S10,
        RegisterARM::S11,
        RegisterARM::S12,
        RegisterARM::S13,
        RegisterARM::S14,
        RegisterARM::S15,
    ];
    S[k as usize]
}

/// IPSR = `e`, EPSR cleared but T, PC = the vector; bookkeeping of the taken
/// exception.
fn jump_to_handler(uc: &mut Unicorn<Board>, e: u32) {
    let vtor = uc.get_data().scs.vtor;
    let vector = read32(uc, vtor + 4 * e);
    // EPSR: T set, IT cleared; IPSR = e; APSR unknown on entry (kept).
    let apsr = reg(uc, RegisterARM::XPSR) & 0xF80F_0000;
    set(uc, RegisterARM::XPSR_NZCVQG, apsr | 1 << 24 | e);
    set(uc, RegisterARM::PC, vector & !1);
    let b = uc.get_data_mut();
    b.scs.pending[e as usize] = false;
    b.scs.active.push(e);
    b.scs.event = true;
    *b.stats.taken.entry(e).or_default() += 1;
    if e == IRQ0 + 55 {
        let since = b.scs.pending_since[e as usize];
        let latency = b.now.saturating_sub(since);
        b.stats.servo_latency.push(latency);
        let w = &mut b.stats.worst_servo;
        if w.len() < 5 || latency > w[w.len() - 1].0 {
            w.push((latency, b.pended_in[e as usize]));
            w.sort_by(|a, b| b.0.cmp(&a.0));
            w.truncate(5);
        }
    }
}

/// The exception that would preempt what runs now, if any.
fn preempting(uc: &Unicorn<Board>) -> Option<u32> {
    let basepri = reg(uc, RegisterARM::BASEPRI);
    let primask = reg(uc, RegisterARM::PRIMASK);
    let s = &uc.get_data().scs;
    s.next_exception(s.execution_priority(basepri, primask))
}

/// Exception return ("Exception return behavior") to `exc_return`, or a tail-chain into a pending
/// exception that may run at the priority returned to.
fn exception_return(uc: &mut Unicorn<Board>, exc_return: u32) -> Result<(), String> {
    let ipsr = reg(uc, RegisterARM::IPSR);
    let popped = uc.get_data_mut().scs.active.pop();
    if popped != Some(ipsr) {
        return Err(format!(
            "exception return from {ipsr} while {popped:?} was active"
        ));
    }
    uc.get_data_mut().scs.event = true;
    // A level-sensitive line still asserted pends again.
    uc.get_data_mut().usb_line();
    // Tail-chain: a pending exception more urgent than the context returned to.
    if let Some(e) = preempting(uc) {
        set(uc, RegisterARM::LR, exc_return);
        jump_to_handler(uc, e);
        return Ok(());
    }
    if exc_return & 0x4 != 0 {
        return Err("return to the process stack: not used by this firmware".into());
    }
    let fp = exc_return & 0x10 == 0;
    let frame = reg(uc, RegisterARM::SP);
    if std::env::var_os("VBOARD_TRACE").is_some() {
        eprintln!(
            "return {exc_return:#x} to {:#x} xpsr {:#x} sp {frame:#x}",
            read32(uc, frame + 24),
            read32(uc, frame + 28)
        );
    }
    for (k, r) in FRAME_REGS.iter().enumerate() {
        let v = read32(uc, frame + 4 * k as u32);
        set(uc, *r, v);
    }
    let pc = read32(uc, frame + 24);
    let xpsr = read32(uc, frame + 28);
    if fp {
        let scs = &mut uc.get_data_mut().scs;
        if scs.fpccr & FPCCR_LSPACT != 0 {
            // Never saved: the registers still hold the context's own values.
            scs.fpccr &= !FPCCR_LSPACT;
            uc.get_data_mut().stats.lazy_skipped += 1;
        } else {
            for k in 0..16u32 {
                let v = read32(uc, frame + 32 + 4 * k);
                set(uc, s_reg(k), v);
            }
            let fpscr = read32(uc, frame + 96);
            set(uc, RegisterARM::FPSCR, fpscr);
        }
    }
    let mut sp = frame + if fp { 0x68 } else { 0x20 };
    if xpsr & (1 << 9) != 0 {
        sp += 4;
    }
    set(uc, RegisterARM::SP, sp);
    set(uc, RegisterARM::XPSR_NZCVQG, xpsr & !(1 << 9));
    let control = reg(uc, RegisterARM::CONTROL);
    set(
        uc,
        RegisterARM::CONTROL,
        if fp { control | 4 } else { control & !4 },
    );
    set(uc, RegisterARM::PC, pc & !1);
    Ok(())
}

impl<'a> Core<'a> {
    /// The core with `image` loaded into flash and `board` on its bus.
    pub fn new(image: Rc<Image>, board: Board) -> Result<Self> {
        let mut uc = Unicorn::new_with_data(Arch::ARM, Mode::THUMB | Mode::MCLASS, board)
            .map_err(|e| anyhow!("unicorn: {e:?}"))?;
        uc.ctl_set_cpu_model(unicorn_engine::ArmCpuModel::CORTEX_M4 as i32)
            .map_err(|e| anyhow!("unicorn cpu model: {e:?}"))?;
        let mut flash_image = vec![0xFFu8; flash::SIZE as usize];
        for s in &image.segments {
            let o = s.addr.wrapping_sub(flash::BASE) as usize;
            if s.addr >= flash::BASE
                && o + s.data.len() <= flash::CONFIG as usize - flash::BASE as usize
            {
                flash_image[o..o + s.data.len()].copy_from_slice(&s.data);
            } else if s.addr < RAM || s.addr >= RAM + RAM_SIZE {
                bail!("ELF segment at {:#010x} is outside flash and RAM", s.addr);
            }
        }
        let program = (flash::CONFIG - flash::BASE) as u64;
        let map = |uc: &mut Unicorn<Board>, a: u64, n: u64, p: Prot| {
            uc.mem_map(a, n, p)
                .map_err(|e| anyhow!("map {a:#x}: {e:?}"))
        };
        map(
            &mut uc,
            u64::from(flash::BASE),
            program,
            Prot::READ | Prot::EXEC,
        )?;
        uc.mem_write(u64::from(flash::BASE), &flash_image[..program as usize])
            .map_err(|e| anyhow!("{e:?}"))?;
        map(&mut uc, u64::from(RAM), u64::from(RAM_SIZE), Prot::ALL)?;
        uc.mem_write(u64::from(RAM), &vec![PAINT; RAM_SIZE as usize])
            .map_err(|e| anyhow!("{e:?}"))?;
        // Everything else a program may address goes through the board: the
        // configuration pages, the peripherals, the system control space.
        for (base, size) in [
            (flash::CONFIG, flash::CONFIG_SIZE),
            (0x4000_0000, 0xB000),
            (0x4001_0000, 0x8000),
            (0x4002_0000, 0x4000),
            (0x4800_0000, 0x2000),
            (0x5000_0000, 0x2000),
            (0xE000_0000, 0x10_0000),
        ] {
            let rb = u64::from(base);
            uc.mmio_map(
                rb,
                u64::from(size),
                Some(move |uc: &mut Unicorn<Board>, o: u64, size: usize| {
                    u64::from(uc.get_data_mut().read((rb + o) as u32, size))
                }),
                Some(
                    move |uc: &mut Unicorn<Board>, o: u64, size: usize, v: u64| {
                        uc.get_data_mut().write((rb + o) as u32, size, v as u32);
                        // CPACR reaches the core at once (the FPU enable).
                        if rb + o == 0xE000_ED88 {
                            let cpacr = uc.get_data().scs.cpacr;
                            let _ = uc.reg_write(RegisterARM::C1_C0_2, u64::from(cpacr));
                        }
                    },
                ),
            )
            .map_err(|e| anyhow!("mmio {base:#x}: {e:?}"))?;
        }
        let mut core = Self {
            uc,
            image,
            flash_image,
            sleeping_at: None,
            periods_closed: 0,
            held_until: 0,
            stack_top: 0,
        };
        core.stack_top = read32(&core.uc, flash::BASE);
        core.install_hooks()?;
        core.reset()?;
        Ok(core)
    }

    fn install_hooks(&mut self) -> Result<()> {
        let code = self.flash_image.clone();
        let top = self.stack_top;
        let mut blocks = Blocks::default();
        let mut unwinder = self.image.section(".debug_frame").and_then(Unwinder::new);
        self.uc
            .add_block_hook(1, 0, move |uc, addr, size| {
                let (n, fp) = *blocks.counts.entry(addr).or_insert_with(|| {
                    let o = addr.wrapping_sub(u64::from(flash::BASE)) as usize;
                    code.get(o..o + size as usize).map_or((1, None), scan_block)
                });
                uc.get_data_mut().lazy_window = None;
                if let Some(at) = fp {
                    if uc.get_data().scs.fpccr & FPCCR_LSPACT != 0 {
                        lazy_save(uc);
                        if at > 0 {
                            let a = addr as u32;
                            uc.get_data_mut().lazy_window = Some((a, a + at));
                        }
                    }
                }
                let sp = reg(uc, RegisterARM::SP);
                if sp < uc.get_data().lowest_sp && sp >= RAM {
                    let chain = unwinder.as_mut().map(|u| {
                        let mut regs = [0u32; 16];
                        for (k, r) in GPRS.iter().enumerate() {
                            regs[k] = reg(uc, *r);
                        }
                        regs[15] = addr as u32;
                        u.chain(regs, top, |a| read32(uc, a))
                    });
                    let b = uc.get_data_mut();
                    b.lowest_sp = sp;
                    b.stats.min_sp = Some((sp, chain.unwrap_or_default()));
                }
                // An exception waits behind a mask: look whether the code just run
                // lifted it (CPSIE, MSR BASEPRI/PRIMASK).
                let unmasked = uc.get_data().masked_pending && preempting(uc).is_some();
                let b = uc.get_data_mut();
                if let Some((from, to, hist)) = b.profile.as_mut() {
                    if b.now >= *from && b.now < *to {
                        *hist.entry(addr as u32).or_insert(0) += u64::from(n);
                    }
                }
                b.block_pc = addr as u32;
                b.instructions += u64::from(n);
                b.now += u64::from(n) * b.cycle_units;
                if b.now >= b.deadline || b.stop || unmasked {
                    let _ = uc.emu_stop();
                }
            })
            .map_err(|e| anyhow!("block hook: {e:?}"))?;
        // Exception return: unicorn raises exception 8 (EXCP_EXCEPTION_EXIT) when a
        // handler branches to an EXC_RETURN value.
        self.uc
            .add_intr_hook(|uc, intno| {
                let pc = reg(uc, RegisterARM::PC);
                if intno == 8 && pc >= 0xFFFF_FFE0 {
                    if let Err(what) = exception_return(uc, pc) {
                        let b = uc.get_data_mut();
                        b.fault = Some(Fault { what, pc: Some(pc) });
                    }
                    // The run loop restarts the core at the new PC, with the state
                    // QEMU derives from the registers recomputed.
                    uc.get_data_mut().stop = true;
                    let _ = uc.emu_stop();
                    return;
                }
                let what = match intno {
                    1 => "an undefined instruction (UDF: a panic or a hard fault)".to_string(),
                    2 => "an SVC instruction (not used by this firmware)".to_string(),
                    7 => "a BKPT instruction (a panic)".to_string(),
                    n => format!("CPU exception {n} (a fault)"),
                };
                let b = uc.get_data_mut();
                b.fault = Some(Fault { what, pc: Some(pc) });
                let _ = uc.emu_stop();
            })
            .map_err(|e| anyhow!("intr hook: {e:?}"))?;
        // The exact instruction of every peripheral access (unicorn brings the program
        // counter up to date before a memory hook, not before an MMIO callback), for
        // the message of an unmodelled access.
        for (base, size) in [(0x4000_0000u64, 0x2000_0000u64), (0xE000_0000, 0x10_0000)] {
            self.uc
                .add_mem_hook(
                    HookType::MEM_READ | HookType::MEM_WRITE,
                    base,
                    base + size - 1,
                    |uc, _kind, _addr, _size, _v| {
                        let pc = reg(uc, RegisterARM::PC);
                        uc.get_data_mut().access_pc = pc;
                        true
                    },
                )
                .map_err(|e| anyhow!("access hook: {e:?}"))?;
        }
        self.uc
            .add_mem_hook(HookType::MEM_UNMAPPED, 1, 0, |uc, kind, addr, size, _v| {
                let pc = reg(uc, RegisterARM::PC);
                let what = format!(
                    "{} of {size} bytes at {addr:#010x}, which nothing is mapped at",
                    if kind == MemType::WRITE_UNMAPPED {
                        "write"
                    } else if kind == MemType::FETCH_UNMAPPED {
                        "fetch"
                    } else {
                        "read"
                    }
                );
                uc.get_data_mut().fault = Some(Fault { what, pc: Some(pc) });
                false
            })
            .map_err(|e| anyhow!("unmapped hook: {e:?}"))?;
        self.uc
            .add_mem_hook(
                HookType::MEM_WRITE_PROT,
                1,
                0,
                |uc, _kind, addr, size, v| {
                    let pc = reg(uc, RegisterARM::PC);
                    let what =
                        format!("write of {size} bytes of {v:#x} at {addr:#010x} in program flash");
                    uc.get_data_mut().fault = Some(Fault { what, pc: Some(pc) });
                    false
                },
            )
            .map_err(|e| anyhow!("write-protect hook: {e:?}"))?;
        // QEMU ends a WFE or WFI by an exception unicorn reports as an invalid
        // instruction; the sleep itself is handled by the hooks below.
        let code = self.flash_image.clone();
        self.uc
            .add_insn_invalid_hook(move |uc| {
                let pc = reg(uc, RegisterARM::PC);
                let o = pc.wrapping_sub(flash::BASE + 2) as usize;
                let hw = code.get(o..o + 2).map(|b| u16::from_le_bytes([b[0], b[1]]));
                matches!(hw, Some(0xBF20 | 0xBF30))
            })
            .map_err(|e| anyhow!("invalid-instruction hook: {e:?}"))?;
        // WFE, WFI and SEV: hooks on every half-word that encodes them in the program
        // (a hook on a half-word that is not an instruction start never fires).
        let mut sleeps = Vec::new();
        for o in (0..self.flash_image.len() - 1).step_by(2) {
            let hw = u16::from_le_bytes([self.flash_image[o], self.flash_image[o + 1]]);
            if matches!(hw, 0xBF20 | 0xBF30 | 0xBF40) {
                sleeps.push((flash::BASE + o as u32, hw));
            }
        }
        for (a, hw) in sleeps {
            let a64 = u64::from(a);
            self.uc
                .add_code_hook(a64, a64, move |uc, _addr, _size| {
                    let b = uc.get_data_mut();
                    if hw == 0xBF40 {
                        b.scs.event = true;
                        return;
                    }
                    if hw == 0xBF20 && b.scs.event {
                        b.scs.event = false;
                        return;
                    }
                    b.stop = true;
                    b.deadline = 0;
                    b.sleep_request = Some(a);
                    let _ = uc.emu_stop();
                })
                .map_err(|e| anyhow!("sleep hook: {e:?}"))?;
        }
        Ok(())
    }

    /// Reset: SP and PC from the vector table, registers cleared, Thread mode.
    pub fn reset(&mut self) -> Result<()> {
        let sp = read32(&self.uc, flash::BASE);
        let pc = read32(&self.uc, flash::BASE + 4);
        let uc = &mut self.uc;
        // R0–R12 (SP and LR are set below).
        for r in &GPRS[..13] {
            set(uc, *r, 0);
        }
        set(uc, RegisterARM::IPSR, 0);
        set(uc, RegisterARM::CONTROL, 0);
        set(uc, RegisterARM::PRIMASK, 0);
        set(uc, RegisterARM::BASEPRI, 0);
        set(uc, RegisterARM::MSP, sp);
        set(uc, RegisterARM::SP, sp);
        set(uc, RegisterARM::LR, 0xFFFF_FFFF);
        set(uc, RegisterARM::XPSR_NZCVQG, 1 << 24);
        // CPACR: the FPU is off after reset; the firmware's start-up code enables it
        // (SCB CPACR), which the board passes on before the next instruction.
        let _ = uc.reg_write(RegisterARM::C1_C0_2, 0);
        uc.get_data_mut().scs.vtor = flash::BASE; // boot from main flash (BOOT0 low)
        set(uc, RegisterARM::PC, pc & !1);
        self.sleeping_at = None;
        Ok(())
    }

    /// Runs until virtual time `until` (units) or a fault.
    pub fn run(&mut self, until: u64) -> Result<Exit> {
        loop {
            // Events due, then a reset if one is due.
            self.uc.get_data_mut().process();
            if let Some(cause) = self.uc.get_data_mut().reset_due.take() {
                let b = self.uc.get_data_mut();
                match cause {
                    ResetCause::Watchdog => b.stats.watchdog_resets += 1,
                    ResetCause::Pin => b.stats.pin_resets += 1,
                    _ => b.stats.software_resets += 1,
                }
                b.reset_peripherals(cause);
                self.reset()?;
                self.held_until = 0;
                continue;
            }
            if let Some(f) = self.uc.get_data_mut().fault.take() {
                return Ok(Exit::Fault(f));
            }
            let b = self.uc.get_data_mut();
            if b.now < self.held_until {
                // Held: the peripherals run on, nothing executes or is taken.
                let from = b.now;
                b.now = b.next_event().min(until).min(self.held_until).max(from + 1);
                let mut closed = self.periods_closed;
                b.close_periods(&mut closed);
                self.periods_closed = closed;
                if b.now >= until {
                    return Ok(Exit::Time);
                }
                continue;
            }
            self.sync_fpu();
            // Take the exception that preempts what runs now.
            let pc = reg(&self.uc, RegisterARM::PC);
            if let Some(e) = preempting(&self.uc) {
                let resume = match self.sleeping_at.take() {
                    Some(a) => a + 2,
                    None => pc,
                };
                enter(&mut self.uc, e, resume);
                continue;
            }
            let waiting = {
                let s = &self.uc.get_data().scs;
                (0..s.pending.len())
                    .any(|e| s.pending[e] && (e < IRQ0 as usize || s.enabled[e - IRQ0 as usize]))
            };
            let b = self.uc.get_data_mut();
            b.masked_pending = waiting;
            b.scs.changed = false;
            let next = b.next_event().min(until);
            if b.now >= until {
                return Ok(Exit::Time);
            }
            if self.sleeping_at.is_some() {
                // Asleep with nothing to take: time jumps to the next event.
                let b = self.uc.get_data_mut();
                if b.scs.event && self.sleeping_at.is_some() {
                    // An event arrived while asleep (WFE): wake past the WFE.
                    b.scs.event = false;
                    let a = self.sleeping_at.take().unwrap_or(0);
                    set(&mut self.uc, RegisterARM::PC, a + 2);
                    continue;
                }
                let b = self.uc.get_data_mut();
                let from = b.now;
                b.now = b.now.max(next);
                let to = b.now;
                b.idle(from, to);
                self.periods_closed = to / crate::time::from_ms(1);
                continue;
            }
            let b = self.uc.get_data_mut();
            b.deadline = next;
            b.stop = false;
            let start = reg(&self.uc, RegisterARM::PC);
            let r = self.uc.emu_start(u64::from(start | 1), 0, 0, 0);
            let mut closed = self.periods_closed;
            self.uc.get_data_mut().close_periods(&mut closed);
            self.periods_closed = closed;
            let b = self.uc.get_data_mut();
            if let Some(a) = b.sleep_request.take() {
                self.sleeping_at = Some(a);
                set(&mut self.uc, RegisterARM::PC, a);
            }
            if let Err(e) = r {
                let b = self.uc.get_data_mut();
                let f = b.fault.take().unwrap_or(Fault {
                    what: format!("the emulator stopped: {e:?}"),
                    pc: None,
                });
                let pc = f.pc.unwrap_or_else(|| reg(&self.uc, RegisterARM::PC));
                return Ok(Exit::Fault(Fault { pc: Some(pc), ..f }));
            }
        }
    }

    /// The deepest the stack went: the lowest RAM byte below the initial stack
    /// pointer that no longer holds the power-on paint (flip-link puts the stack at
    /// the bottom of RAM, so everything below is untouched).
    pub fn stack_depth(&self) -> (u32, u32) {
        let mut ram = vec![0u8; (self.stack_top - RAM) as usize];
        let _ = self.uc.mem_read(u64::from(RAM), &mut ram);
        let untouched = ram.iter().position(|&b| b != PAINT).unwrap_or(ram.len()) as u32;
        (self.stack_top - RAM - untouched, untouched)
    }

    /// Passes the firmware's CPACR (the FPU enable) on to the core.
    fn sync_fpu(&mut self) {
        let cpacr = self.uc.get_data().scs.cpacr;
        if reg(&self.uc, RegisterARM::C1_C0_2) != cpacr {
            let _ = self.uc.reg_write(RegisterARM::C1_C0_2, u64::from(cpacr));
        }
    }

    /// Names the function at `pc`.
    pub fn function_at(&self, pc: u32) -> String {
        self.image.function_at(pc)
    }
}

#[cfg(test)]
mod tests {
    //! Lazy FP state preservation on a hand-assembled program: Thread mode loads
    //! S0 = 1.0 and pends PendSV; the handler reads FPCCR and FPCAR, optionally
    //! overwrites S0 with 2.0, reads FPCCR again and returns; Thread mode then copies
    //! S0 to R3. Encodings from the ARMv7-M ARM (MOVW/MOVT T3/T1, STR/LDR T1,
    //! VMOV core register to/from single-precision T1, ISB, BX, B).
    use super::*;
    use crate::board::MachineSide;
    use crate::elf::Segment;

    /// MOVW (`top` false) or MOVT of `imm` into `rd`.
    fn mov16(rd: u16, imm: u16, top: bool) -> [u16; 2] {
        let i = (imm >> 11) & 1;
        let imm4 = imm >> 12;
        let imm3 = (imm >> 8) & 7;
        let hw1 = if top { 0xF2C0 } else { 0xF240 } | i << 10 | imm4;
        [hw1, imm3 << 12 | rd << 8 | (imm & 0xFF)]
    }

    /// `rd` = `v` (MOVW then MOVT).
    fn load(rd: u16, v: u32) -> Vec<u16> {
        let mut c = mov16(rd, v as u16, false).to_vec();
        c.extend(mov16(rd, (v >> 16) as u16, true));
        c
    }

    const ISB: [u16; 2] = [0xF3BF, 0x8F6F];

    /// Runs the program; `lspen` leaves FPCCR.LSPEN set (else it is cleared first),
    /// `touch` makes the handler execute a floating-point instruction. Returns the
    /// core after 2 000 instructions' time.
    fn run(lspen: bool, touch: bool) -> Core<'static> {
        let mut thread = Vec::new();
        if !lspen {
            thread.extend(load(0, 0xE000_EF34));
            thread.extend(load(1, 0x8000_0000));
            thread.push(0x6001); // str r1, [r0]
        }
        thread.extend(load(0, 0xE000_ED88)); // CPACR: CP10 and CP11 full access
        thread.extend(load(1, 0x00F0_0000));
        thread.push(0x6001);
        thread.extend(ISB);
        thread.extend(load(2, 0x3F80_0000)); // 1.0
        thread.extend([0xEE00, 0x2A10]); // vmov s0, r2
        thread.extend(load(0, 0xE000_ED04)); // ICSR.PENDSVSET
        thread.extend(load(1, 0x1000_0000));
        thread.push(0x6001);
        thread.extend(ISB);
        thread.extend([0xEE10, 0x3A10]); // vmov r3, s0
        thread.push(0xE7FE); // b .
        let mut handler = load(0, 0xE000_EF34);
        handler.push(0x6804); // ldr r4, [r0]      FPCCR
        handler.push(0x6845); // ldr r5, [r0, #4]  FPCAR
        if touch {
            handler.extend(load(6, 0x4000_0000)); // 2.0
            handler.extend([0xEE00, 0x6A10]); // vmov s0, r6
        }
        handler.push(0x6807); // ldr r7, [r0]      FPCCR again
        handler.push(0x4770); // bx lr
        execute(&thread, &[(14, handler)])
    }

    /// Runs `thread` from reset with `handlers` (exception number, code) in the vector
    /// table, for 2 000 instructions' time.
    fn execute(thread: &[u16], handlers: &[(usize, Vec<u16>)]) -> Core<'static> {
        let base = flash::BASE;
        let mut image = vec![0u8; 0x800];
        let mut word = |o: usize, v: u32| image[o..o + 4].copy_from_slice(&v.to_le_bytes());
        word(0, RAM + 0x1000);
        word(4, base + 0x101);
        for (k, (e, _)) in handlers.iter().enumerate() {
            word(4 * e, base + 0x201 + 0x100 * k as u32);
        }
        let mut code = vec![(0x100, thread)];
        for (k, (_, h)) in handlers.iter().enumerate() {
            code.push((0x200 + 0x100 * k, h.as_slice()));
        }
        for (at, c) in code {
            for (k, hw) in c.iter().enumerate() {
                image[at + 2 * k..at + 2 * k + 2].copy_from_slice(&hw.to_le_bytes());
            }
        }
        let image = Image::from_segments(vec![Segment {
            addr: base,
            data: image,
        }]);
        let machine = pkmc::config::MachineConfig::cartesian_xyz();
        let wiring = crate::wiring::mixed();
        let side = MachineSide::new(machine, &[0, 0, 0], &[], wiring.amp_lines.len()).unwrap();
        let board = Board::new(wiring, side, vec![0xFF; flash::CONFIG_SIZE as usize]);
        let mut core = Core::new(Rc::new(image), board).unwrap();
        match core.run(2000 * 170).unwrap() {
            Exit::Time => {}
            Exit::Fault(f) => panic!("fault: {} at {:?}", f.what, f.pc),
        }
        core
    }

    fn r(core: &Core, r: RegisterARM) -> u32 {
        reg(&core.uc, r)
    }

    #[test]
    fn deferred_save_written_by_the_handlers_first_fp_instruction() {
        let core = run(true, true);
        let fpcar = r(&core, RegisterARM::R5);
        // At entry: LSPACT and THREAD set, FPCAR at the frame's S0 slot (the frame
        // is 0x68 bytes below the 8-aligned stack top).
        assert_eq!(r(&core, RegisterARM::R4) & 0x9, 0x9, "FPCCR at entry");
        assert_eq!(fpcar, RAM + 0x1000 - 0x68 + 32);
        // The first FP instruction saved the Thread's S0 (1.0) and cleared LSPACT.
        assert_eq!(read32(&core.uc, fpcar), 0x3F80_0000);
        assert_eq!(r(&core, RegisterARM::R7) & 1, 0, "FPCCR after the save");
        // The return restored S0 from the frame, over the handler's 2.0.
        assert_eq!(r(&core, RegisterARM::R3), 0x3F80_0000);
        let b = core.uc.get_data();
        assert_eq!((b.stats.lazy_saves, b.stats.lazy_skipped), (1, 0));
        assert_eq!(b.scs.fpccr & 1, 0);
    }

    #[test]
    fn deferred_save_never_written_when_the_handler_does_no_fp() {
        let core = run(true, false);
        let fpcar = r(&core, RegisterARM::R5);
        assert_eq!(r(&core, RegisterARM::R4) & 1, 1);
        assert_eq!(r(&core, RegisterARM::R7) & 1, 1, "still deferred");
        // The slot still holds the power-on paint: nothing was stacked there.
        assert_eq!(read32(&core.uc, fpcar), u32::from_le_bytes([PAINT; 4]));
        // The return cleared LSPACT and left S0 as it was.
        assert_eq!(r(&core, RegisterARM::R3), 0x3F80_0000);
        let b = core.uc.get_data();
        assert_eq!((b.stats.lazy_saves, b.stats.lazy_skipped), (0, 1));
        assert_eq!(b.scs.fpccr & 1, 0);
    }

    #[test]
    fn a_preempting_handler_saves_the_deferred_state_of_the_frame_below() {
        // Thread: S0 = 1.0, PendSV at the lowest priority, SysTick at the highest;
        // pend PendSV. PendSV (no FP) reads FPCAR, pends SysTick, which preempts it
        // with a basic frame (PendSV has not used the FPU) and writes S0 = 2.0: the
        // save goes to the Thread's frame. PendSV returns and restores S0 = 1.0.
        let mut thread = load(0, 0xE000_ED20); // SHPR3: SysTick 0x00, PendSV 0xF0
        thread.extend(load(1, 0x00F0_0000));
        thread.push(0x6001);
        thread.extend(load(0, 0xE000_ED88));
        thread.extend(load(1, 0x00F0_0000));
        thread.push(0x6001);
        thread.extend(ISB);
        thread.extend(load(2, 0x3F80_0000));
        thread.extend([0xEE00, 0x2A10]); // vmov s0, r2
        thread.extend(load(0, 0xE000_ED04));
        thread.extend(load(1, 0x1000_0000)); // PENDSVSET
        thread.push(0x6001);
        thread.extend(ISB);
        thread.extend([0xEE10, 0x3A10]); // vmov r3, s0
        thread.push(0xE7FE);
        let mut pendsv = load(0, 0xE000_EF34);
        pendsv.push(0x6845); // ldr r5, [r0, #4]  FPCAR
        pendsv.extend(load(0, 0xE000_ED04));
        pendsv.extend(load(1, 0x0400_0000)); // PENDSTSET
        pendsv.push(0x6001);
        pendsv.extend(ISB);
        pendsv.push(0x4770);
        let mut systick = load(6, 0x4000_0000);
        systick.extend([0xEE00, 0x6A10]); // vmov s0, r6
        systick.push(0x466C); // mov r4, sp (SysTick's frame: basic, below PendSV's)
        systick.push(0x4770);
        let core = execute(&thread, &[(14, pendsv), (15, systick)]);
        let fpcar = r(&core, RegisterARM::R5);
        assert_eq!(fpcar, RAM + 0x1000 - 0x68 + 32, "the Thread's frame");
        assert_eq!(
            read32(&core.uc, fpcar),
            0x3F80_0000,
            "saved by SysTick's VMOV"
        );
        // SysTick's own frame is 8 words right below the Thread's 26 (PendSV pushes
        // nothing): SP in SysTick = the Thread's frame - 0x20.
        assert_eq!(r(&core, RegisterARM::R4), RAM + 0x1000 - 0x68 - 0x20);
        assert_eq!(r(&core, RegisterARM::R3), 0x3F80_0000);
        let b = core.uc.get_data();
        assert_eq!((b.stats.lazy_saves, b.stats.lazy_skipped), (1, 0));
        assert_eq!(*b.stats.taken.get(&15).unwrap_or(&0), 1);
    }

    #[test]
    fn without_lspen_the_fp_state_is_stacked_at_entry() {
        let core = run(false, false);
        assert_eq!(r(&core, RegisterARM::R4) & 1, 0, "nothing deferred");
        let slot = RAM + 0x1000 - 0x68 + 32;
        assert_eq!(read32(&core.uc, slot), 0x3F80_0000);
        assert_eq!(r(&core, RegisterARM::R3), 0x3F80_0000);
        let b = core.uc.get_data();
        assert_eq!((b.stats.lazy_saves, b.stats.lazy_skipped), (0, 0));
    }
}
