//! The call chain at an instant, unwound from the firmware's own call-frame
//! information (the ELF's `.debug_frame`, DWARF 4 section 6.4): for each frame the
//! rule for the canonical frame address (CFA) and for the saved registers at the
//! current instruction give the caller's SP, LR and callee-saved registers; the
//! caller's PC is the return address. An EXC_RETURN value in place of a return
//! address is an exception entry: the interrupted context's R0–R3, R12, LR, PC and
//! xPSR are in the frame at the CFA (basic or extended, realigned by xPSR bit 9),
//! and the unwind goes on in the interrupted code ("Exception entry behavior",
//! ARMv7-M ARM).

use gimli::{
    BaseAddresses, CfaRule, DebugFrame, EndianSlice, FrameDescriptionEntry, LittleEndian, Register,
    RegisterRule, UnwindContext, UnwindSection,
};

type R = EndianSlice<'static, LittleEndian>;

/// One frame of a chain.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Frame {
    /// The instruction executing in the frame: the innermost frame's, an
    /// interrupted frame's next, or the call instruction of a caller.
    pub pc: u32,
    /// The frame was interrupted by an exception (its PC came from a stacked frame).
    pub interrupted: bool,
}

/// The firmware's call-frame information, indexed by address.
pub struct Unwinder {
    frame: DebugFrame<R>,
    fdes: Vec<FrameDescriptionEntry<R>>,
    ctx: UnwindContext<usize>,
}

/// The registers an unwind starts from: R0–R12, SP, LR, PC.
pub type Regs = [u32; 16];

const SP: usize = 13;
const LR: usize = 14;

impl Unwinder {
    /// The index of `debug_frame` (the section's bytes, copied).
    pub fn new(debug_frame: &[u8]) -> Option<Self> {
        let bytes: &'static [u8] = Box::leak(debug_frame.to_vec().into_boxed_slice());
        let mut frame = DebugFrame::new(bytes, LittleEndian);
        frame.set_address_size(4);
        let bases = BaseAddresses::default();
        let mut fdes = Vec::new();
        let mut entries = frame.entries(&bases);
        while let Ok(Some(e)) = entries.next() {
            if let gimli::CieOrFde::Fde(partial) = e {
                if let Ok(fde) = partial.parse(DebugFrame::cie_from_offset) {
                    fdes.push(fde);
                }
            }
        }
        if fdes.is_empty() {
            return None;
        }
        fdes.sort_by_key(|f| f.initial_address());
        Some(Self {
            frame,
            fdes,
            ctx: UnwindContext::new(),
        })
    }

    fn fde(&self, pc: u32) -> Option<&FrameDescriptionEntry<R>> {
        let pc = u64::from(pc);
        let i = self.fdes.partition_point(|f| f.initial_address() <= pc);
        let f = self.fdes.get(i.checked_sub(1)?)?;
        (pc < f.initial_address() + f.len()).then_some(f)
    }

    /// The chain from `regs` (the innermost frame first), reading memory through
    /// `read`; it ends at a frame without call-frame information (the reset handler's
    /// start-up code), at a return address outside the program, or after 64 frames.
    /// `top` is the initial stack pointer: no frame lies above it.
    pub fn chain(&mut self, mut regs: Regs, top: u32, read: impl Fn(u32) -> u32) -> Vec<Frame> {
        let mut out = vec![Frame {
            pc: regs[15],
            interrupted: false,
        }];
        // The innermost PC is an instruction; return addresses point after the call,
        // so they are looked up one byte back (the call may end its function).
        let mut lookup = regs[15];
        while out.len() < 64 {
            let Some(fde) = self.fde(lookup).cloned() else {
                break;
            };
            let bases = BaseAddresses::default();
            let Ok(row) =
                fde.unwind_info_for_address(&self.frame, &bases, &mut self.ctx, u64::from(lookup))
            else {
                break;
            };
            let cfa = match row.cfa() {
                CfaRule::RegisterAndOffset { register, offset } => {
                    let base = regs.get(usize::from(register.0)).copied().unwrap_or(0);
                    (i64::from(base) + offset) as u32
                }
                CfaRule::Expression(_) => break,
            };
            let mut caller = regs;
            for r in 0..=LR {
                match row.register(Register(r as u16)) {
                    RegisterRule::Offset(o) => caller[r] = read((i64::from(cfa) + o) as u32),
                    RegisterRule::ValOffset(o) => caller[r] = (i64::from(cfa) + o) as u32,
                    RegisterRule::Register(from) => {
                        caller[r] = regs.get(usize::from(from.0)).copied().unwrap_or(0)
                    }
                    _ => {}
                }
            }
            caller[SP] = cfa;
            let ret = caller[LR];
            if ret >= 0xFFFF_FFE0 {
                // An exception entry: the interrupted context is stacked at the CFA.
                let f = cfa;
                for (k, r) in [0usize, 1, 2, 3, 12, LR].iter().enumerate() {
                    caller[*r] = read(f + 4 * k as u32);
                }
                let pc = read(f + 24) & !1;
                let xpsr = read(f + 28);
                let size = if ret & 0x10 == 0 { 0x68 } else { 0x20 };
                caller[SP] = f + size + if xpsr & (1 << 9) != 0 { 4 } else { 0 };
                caller[15] = pc;
                lookup = pc;
                out.push(Frame {
                    pc,
                    interrupted: true,
                });
            } else {
                if ret & 1 == 0 || ret < 0x0800_0000 || ret >= 0x0808_0000 {
                    break;
                }
                let pc = ret & !1;
                caller[15] = pc;
                lookup = pc - 1;
                // The call instruction: BL (32 bits) or BLX Rm (16 bits) just before.
                let before = read(pc - 4);
                let bl = before & 0xF800 == 0xF000 && (before >> 16) & 0xD000 == 0xD000;
                out.push(Frame {
                    pc: if bl { pc - 4 } else { pc - 2 },
                    interrupted: false,
                });
            }
            if caller == regs {
                // No progress (start-up code whose rules name itself): not a frame.
                out.pop();
                break;
            }
            if caller[SP] < regs[SP] || caller[SP] > top {
                break;
            }
            regs = caller;
        }
        out
    }
}

#[cfg(test)]
mod tests {
    //! A hand-encoded `.debug_frame` (DWARF 4 section 6.4.1: a CIE, then FDEs) for
    //! two functions that push {r7, lr} first, and a stack holding a call from one
    //! into the other inside an exception handler.
    use super::*;
    use std::collections::HashMap;

    fn cie() -> Vec<u8> {
        // CIE id, version 1, no augmentation, code align 2, data align -4, return
        // address r14, DW_CFA_def_cfa r13 + 0, padding.
        let body = [
            0xFF, 0xFF, 0xFF, 0xFF, 1, 0, 2, 0x7C, 14, 0x0C, 13, 0, 0, 0, 0, 0,
        ];
        let mut v = (body.len() as u32).to_le_bytes().to_vec();
        v.extend(body);
        v
    }

    /// The FDE of a function at `at` of `len` bytes whose first instruction (2
    /// bytes) is PUSH {r7, lr}.
    fn fde(at: u32, len: u32) -> Vec<u8> {
        let mut body = 0u32.to_le_bytes().to_vec(); // its CIE at offset 0
        body.extend(at.to_le_bytes());
        body.extend(len.to_le_bytes());
        // advance 1 (2 bytes); CFA = SP + 8; LR at CFA-4; R7 at CFA-8; padding.
        body.extend([0x41, 0x0E, 8, 0x8E, 1, 0x87, 2, 0, 0, 0, 0, 0]);
        let mut v = (body.len() as u32).to_le_bytes().to_vec();
        v.extend(body);
        v
    }

    #[test]
    fn unwinds_calls_and_an_exception_frame() {
        let mut section = cie();
        section.extend(fde(0x0800_0100, 0x20));
        section.extend(fde(0x0800_0200, 0x40));
        let mut u = Unwinder::new(&section).expect("FDEs");
        let sp = 0x2000_0F00;
        let mut mem: HashMap<u32, u32> = HashMap::new();
        mem.insert(sp, 0x1111_1111); // f's saved r7
        mem.insert(sp + 4, 0x0800_0211); // f's return into g, after a BL at 0x020C
        mem.insert(0x0800_020C, 0xF800_F000); // that BL (two half-words)
        mem.insert(sp + 8, 0x2222_2222); // g's saved r7
        mem.insert(sp + 12, 0xFFFF_FFF9); // g is a handler: EXC_RETURN (basic frame)
        let frame = sp + 16;
        mem.insert(frame + 24, 0x0800_0301); // interrupted PC (no FDE: the end)
        mem.insert(frame + 28, 0x0100_0000); // xPSR, not realigned
        let mut regs = [0u32; 16];
        regs[13] = sp;
        regs[15] = 0x0800_0104; // in f, after its push
        let read = |a: u32| {
            if let Some(v) = mem.get(&a) {
                return *v;
            }
            // The half-word view of the BL for an unaligned read.
            let lo = mem.get(&(a & !3)).copied().unwrap_or(0);
            let hi = mem.get(&((a & !3) + 4)).copied().unwrap_or(0);
            let sh = 8 * (a & 3);
            if sh == 0 {
                lo
            } else {
                lo >> sh | hi << (32 - sh)
            }
        };
        let chain = u.chain(regs, 0x2000_1000, read);
        let pcs: Vec<(u32, bool)> = chain.iter().map(|f| (f.pc, f.interrupted)).collect();
        assert_eq!(
            pcs,
            vec![
                (0x0800_0104, false),
                (0x0800_020C, false),
                (0x0800_0300, true)
            ]
        );
    }

    #[test]
    fn no_frames_without_fdes() {
        assert!(Unwinder::new(&cie()).is_none());
    }
}
