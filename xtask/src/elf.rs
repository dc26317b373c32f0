//! The firmware images' layout, read from their ELF files, against the memory map of the part
//! each is built for (issue 55: the F405 image was linked with QEMU's map and would not boot).

/// One section of an ELF32 file.
#[derive(Debug, Clone, PartialEq)]
pub struct Section {
    /// Its name.
    pub name: String,
    /// Its address.
    pub addr: u32,
    /// Its size [bytes].
    pub size: u32,
    /// Whether it occupies memory on the part (`SHF_ALLOC`).
    pub alloc: bool,
}

/// What the layout check reads of an image: its sections and the stack's start.
#[derive(Debug, Clone, PartialEq)]
pub struct Layout {
    /// The sections.
    pub sections: Vec<Section>,
    /// The address of `_stack_start` (cortex-m-rt's initial stack pointer).
    pub stack_start: Option<u32>,
}

/// A part's memory: flash and RAM, `(origin, length)` each, from its data sheet.
#[derive(Debug, Clone, Copy)]
pub struct Part {
    /// Its name.
    pub name: &'static str,
    /// Flash (code).
    pub flash: (u32, u32),
    /// SRAM.
    pub ram: (u32, u32),
}

/// QEMU's mps2-an386 (Cortex-M4): code at 0, 4 MiB; SRAM at 0x2000_0000, 4 MiB.
pub const MPS2_AN386: Part = Part {
    name: "QEMU mps2-an386",
    flash: (0x0000_0000, 4 << 20),
    ram: (0x2000_0000, 4 << 20),
};

/// STM32F405RG (reference manual RM0090, memory map; data sheet, memory map): flash at 0x0800_0000, 1 MiB; SRAM1 + SRAM2 at
/// 0x2000_0000, 128 KiB (the CCM RAM at 0x1000_0000 is not used).
pub const STM32F405RG: Part = Part {
    name: "STM32F405RG",
    flash: (0x0800_0000, 1 << 20),
    ram: (0x2000_0000, 128 << 10),
};

/// The sections and `_stack_start` of a little-endian ELF32 file.
pub fn layout(d: &[u8]) -> Option<Layout> {
    let u16_at = |o: usize| Some(u16::from_le_bytes(d.get(o..o + 2)?.try_into().ok()?));
    let u32_at = |o: usize| Some(u32::from_le_bytes(d.get(o..o + 4)?.try_into().ok()?));
    if d.get(..5)? != b"\x7fELF\x01" {
        return None;
    }
    let shoff = u32_at(0x20)? as usize;
    let shentsize = u16_at(0x2e)? as usize;
    let shnum = u16_at(0x30)? as usize;
    let shstrndx = u16_at(0x32)? as usize;
    let header = |i: usize| shoff + i * shentsize;
    let name_at = |table: usize, at: usize| -> Option<String> {
        let start = table + at;
        let end = d.get(start..)?.iter().position(|&b| b == 0)?;
        Some(String::from_utf8_lossy(&d[start..start + end]).into_owned())
    };
    let names = u32_at(header(shstrndx) + 16)? as usize;
    let mut sections = Vec::with_capacity(shnum);
    let mut stack_start = None;
    for i in 0..shnum {
        let h = header(i);
        let flags = u32_at(h + 8)?;
        sections.push(Section {
            name: name_at(names, u32_at(h)? as usize)?,
            addr: u32_at(h + 12)?,
            size: u32_at(h + 20)?,
            alloc: flags & 0x2 != 0,
        });
        // SHT_SYMTAB: 16-byte entries, names in the string table its sh_link names.
        if u32_at(h + 4)? == 2 {
            let (offset, size) = (u32_at(h + 16)? as usize, u32_at(h + 20)? as usize);
            let strings = u32_at(header(u32_at(h + 24)? as usize) + 16)? as usize;
            for e in (offset..offset + size).step_by(16) {
                if name_at(strings, u32_at(e)? as usize)? == "_stack_start" {
                    stack_start = Some(u32_at(e + 4)?);
                }
            }
        }
    }
    Some(Layout {
        sections,
        stack_start,
    })
}

impl Layout {
    /// The total size of the sections named `name` [bytes].
    pub fn size(&self, name: &str) -> u64 {
        self.sections
            .iter()
            .filter(|s| s.name == name)
            .map(|s| u64::from(s.size))
            .sum()
    }

    /// What is wrong with the image on `part`: the vector table not at the start of flash,
    /// the stack not starting at the top of RAM, a section outside flash and RAM. Empty when
    /// it fits.
    pub fn misfits(&self, part: &Part) -> Vec<String> {
        let within = |(origin, len): (u32, u32), s: &Section| {
            u64::from(s.addr) >= u64::from(origin)
                && u64::from(s.addr) + u64::from(s.size) <= u64::from(origin) + u64::from(len)
        };
        let mut wrong = Vec::new();
        match self.sections.iter().find(|s| s.name == ".vector_table") {
            Some(v) if v.addr == part.flash.0 => {}
            Some(v) => wrong.push(format!(
                "the vector table is at {:#010x}, not at the start of {}'s flash ({:#010x})",
                v.addr, part.name, part.flash.0
            )),
            None => wrong.push("no .vector_table section".into()),
        }
        let top = u64::from(part.ram.0) + u64::from(part.ram.1);
        match self.stack_start {
            Some(s) if u64::from(s) == top => {}
            Some(s) => wrong.push(format!(
                "_stack_start is {s:#010x}, not the top of {}'s RAM ({top:#010x})",
                part.name
            )),
            None => wrong.push("no _stack_start symbol".into()),
        }
        for s in self.sections.iter().filter(|s| s.alloc && s.size > 0) {
            if !within(part.flash, s) && !within(part.ram, s) {
                wrong.push(format!(
                    "{} ({:#010x}, {} bytes) lies outside {}'s flash and RAM",
                    s.name, s.addr, s.size, part.name
                ));
            }
        }
        wrong
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn section(name: &str, addr: u32, size: u32) -> Section {
        Section {
            name: name.into(),
            addr,
            size,
            alloc: true,
        }
    }

    /// Issue 55, point 1: the F405 image linked with QEMU's map (vector table at 0, stack at
    /// 0x2040_0000) is refused for the part, and the same sections at the part's addresses pass.
    #[test]
    fn an_image_linked_for_another_map_is_named() {
        let qemu = Layout {
            sections: vec![
                section(".vector_table", 0, 0x188),
                section(".text", 0x188, 70_000),
                section(".bss", 0x2000_0000, 20_000),
            ],
            stack_start: Some(0x2040_0000),
        };
        assert!(qemu.misfits(&MPS2_AN386).is_empty());
        let wrong = qemu.misfits(&STM32F405RG);
        assert_eq!(wrong.len(), 4, "{wrong:?}");
        assert!(
            wrong[0].contains("vector table is at 0x00000000"),
            "{wrong:?}"
        );
        assert!(wrong[1].contains("_stack_start is 0x20400000"), "{wrong:?}");
        let board = Layout {
            sections: vec![
                section(".vector_table", 0x0800_0000, 0x188),
                section(".text", 0x0800_0188, 70_000),
                section(".bss", 0x2000_0000, 20_000),
            ],
            stack_start: Some(0x2002_0000),
        };
        assert!(board.misfits(&STM32F405RG).is_empty());
        assert_eq!(board.size(".text"), 70_000);
    }
}
