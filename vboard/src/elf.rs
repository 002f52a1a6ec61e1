//! The firmware image: the loadable segments of a 32-bit little-endian ARM ELF (placed
//! at their load addresses, as a flash programmer writes them) and its function
//! symbols (to name the function of an instruction address).

use anyhow::{bail, Context, Result};

/// One block of bytes at its load (physical) address.
pub struct Segment {
    /// Load address.
    pub addr: u32,
    /// The bytes (file size; the zero-filled rest of a segment is not loaded).
    pub data: Vec<u8>,
}

/// A symbol of the image.
#[derive(Clone)]
pub struct Symbol {
    /// Start address (Thumb bit cleared).
    pub addr: u32,
    /// Size in bytes.
    pub size: u32,
    /// Demangled name.
    pub name: String,
    /// A function (else an object).
    pub func: bool,
}

/// The parts of the ELF the board needs.
pub struct Image {
    /// Loadable segments.
    pub segments: Vec<Segment>,
    /// Function and object symbols, sorted by address.
    pub symbols: Vec<Symbol>,
    /// Raw file, for section look-ups.
    raw: Vec<u8>,
}

fn u16_at(b: &[u8], o: usize) -> Result<u16> {
    Ok(u16::from_le_bytes(
        b.get(o..o + 2).context("ELF truncated")?.try_into()?,
    ))
}

fn u32_at(b: &[u8], o: usize) -> Result<u32> {
    Ok(u32::from_le_bytes(
        b.get(o..o + 4).context("ELF truncated")?.try_into()?,
    ))
}

/// A section header's fields the board uses.
struct Section {
    name: u32,
    kind: u32,
    offset: u32,
    size: u32,
    link: u32,
}

impl Image {
    /// Parses `raw`, an ELF32 LE ARM executable.
    pub fn parse(raw: Vec<u8>) -> Result<Self> {
        if raw.get(0..4) != Some(b"\x7fELF") || raw.get(4) != Some(&1) || raw.get(5) != Some(&1) {
            bail!("not a 32-bit little-endian ELF file");
        }
        if u16_at(&raw, 18)? != 40 {
            bail!("ELF machine {} is not ARM (40)", u16_at(&raw, 18)?);
        }
        let phoff = u32_at(&raw, 28)? as usize;
        let phentsize = u16_at(&raw, 42)? as usize;
        let phnum = u16_at(&raw, 44)? as usize;
        let mut segments = Vec::new();
        for i in 0..phnum {
            let p = phoff + i * phentsize;
            if u32_at(&raw, p)? != 1 {
                continue; // not PT_LOAD
            }
            let offset = u32_at(&raw, p + 4)? as usize;
            let paddr = u32_at(&raw, p + 12)?;
            let filesz = u32_at(&raw, p + 16)? as usize;
            if filesz == 0 {
                continue;
            }
            let data = raw
                .get(offset..offset + filesz)
                .context("ELF segment beyond the file")?
                .to_vec();
            segments.push(Segment { addr: paddr, data });
        }
        let mut image = Self {
            segments,
            symbols: Vec::new(),
            raw,
        };
        image.read_symbols()?;
        Ok(image)
    }

    /// An image of bare segments with no symbols (the core's own tests).
    #[cfg(test)]
    pub fn from_segments(segments: Vec<Segment>) -> Self {
        Self {
            segments,
            symbols: Vec::new(),
            raw: Vec::new(),
        }
    }

    fn sections(&self) -> Result<Vec<Section>> {
        let b = &self.raw;
        let shoff = u32_at(b, 32)? as usize;
        let shentsize = u16_at(b, 46)? as usize;
        let shnum = u16_at(b, 48)? as usize;
        (0..shnum)
            .map(|i| {
                let s = shoff + i * shentsize;
                Ok(Section {
                    name: u32_at(b, s)?,
                    kind: u32_at(b, s + 4)?,
                    offset: u32_at(b, s + 16)?,
                    size: u32_at(b, s + 20)?,
                    link: u32_at(b, s + 24)?,
                })
            })
            .collect()
    }

    fn read_symbols(&mut self) -> Result<()> {
        let secs = self.sections()?;
        let mut symbols = Vec::new();
        for s in secs.iter().filter(|s| s.kind == 2) {
            let strtab = secs
                .get(s.link as usize)
                .context("symbol table without strings")?;
            for k in 0..(s.size / 16) as usize {
                let e = s.offset as usize + k * 16;
                let name = u32_at(&self.raw, e)?;
                let value = u32_at(&self.raw, e + 4)?;
                let size = u32_at(&self.raw, e + 8)?;
                let info = self.raw[e + 12];
                let kind = info & 0xF;
                if kind != 1 && kind != 2 {
                    continue; // neither object nor function
                }
                let raw_name = cstr(&self.raw, (strtab.offset + name) as usize);
                symbols.push(Symbol {
                    addr: value & !1,
                    size,
                    name: format!("{:#}", rustc_demangle::demangle(&raw_name)),
                    func: kind == 2,
                });
            }
        }
        symbols.sort_by_key(|s| s.addr);
        self.symbols = symbols;
        Ok(())
    }

    /// The contents of the section called `name` (e.g. `.debug_frame`), if any.
    pub fn section(&self, name: &str) -> Option<&[u8]> {
        let secs = self.sections().ok()?;
        let names = secs.get(usize::from(u16_at(&self.raw, 50).ok()?))?;
        let s = secs
            .iter()
            .find(|s| cstr(&self.raw, (names.offset + s.name) as usize) == name)?;
        self.raw
            .get(s.offset as usize..s.offset as usize + s.size as usize)
    }

    /// The symbol called `name` (exact, demangled), if any.
    pub fn symbol(&self, name: &str) -> Option<&Symbol> {
        self.symbols.iter().find(|s| s.name == name)
    }

    /// The function containing `addr`, as "name+offset", or the address alone.
    pub fn function_at(&self, addr: u32) -> String {
        let addr = addr & !1;
        let i = self.symbols.partition_point(|s| s.addr <= addr);
        for s in self.symbols[..i].iter().rev() {
            if s.func && addr < s.addr + s.size.max(1) {
                return format!("{}+{:#x}", s.name, addr - s.addr);
            }
            if s.func && s.addr + 0x10000 < addr {
                break;
            }
        }
        format!("{addr:#010x} (no function)")
    }
}

fn cstr(b: &[u8], o: usize) -> String {
    let end = b[o.min(b.len())..]
        .iter()
        .position(|&c| c == 0)
        .map_or(b.len(), |p| o + p);
    String::from_utf8_lossy(&b[o.min(b.len())..end]).into_owned()
}
