//! QEMU's C plugin API (version 1, QEMU 7.2), declared by hand, and the
//! plugin's entry points. The only module with `unsafe`: every call into
//! QEMU and every pointer QEMU hands over is here; the rest of the crate
//! is safe Rust behind one mutex.
#![allow(unsafe_code)]

use std::ffi::{c_char, c_int, c_uint, c_void, CStr, CString};
use std::sync::{Mutex, MutexGuard, PoisonError};

use crate::counter::{parse_args, Counter};

/// `qemu_plugin_id_t`: `uint64_t`.
type PluginId = u64;

/// `struct qemu_plugin_tb`: opaque, only ever behind a pointer.
#[repr(C)]
struct QemuPluginTb {
    _opaque: [u8; 0],
}

/// `struct qemu_plugin_insn`: opaque.
#[repr(C)]
struct QemuPluginInsn {
    _opaque: [u8; 0],
}

/// `enum qemu_plugin_cb_flags`: `QEMU_PLUGIN_CB_NO_REGS` (the callback does
/// not touch the CPU's registers). A C enum is passed as an `int`.
const QEMU_PLUGIN_CB_NO_REGS: c_int = 0;

/// `qemu_plugin_vcpu_tb_trans_cb_t`
type TbTransCb = extern "C" fn(PluginId, *mut QemuPluginTb);
/// `qemu_plugin_vcpu_udata_cb_t`
type VcpuUdataCb = extern "C" fn(c_uint, *mut c_void);
/// `qemu_plugin_udata_cb_t`
type UdataCb = extern "C" fn(PluginId, *mut c_void);

// Resolved against the qemu-system-arm executable when QEMU loads the
// plugin (it exports its plugin API to plugins).
extern "C" {
    fn qemu_plugin_register_vcpu_tb_trans_cb(id: PluginId, cb: TbTransCb);
    fn qemu_plugin_register_vcpu_tb_exec_cb(
        tb: *mut QemuPluginTb,
        cb: VcpuUdataCb,
        flags: c_int,
        userdata: *mut c_void,
    );
    fn qemu_plugin_tb_n_insns(tb: *const QemuPluginTb) -> usize;
    fn qemu_plugin_tb_get_insn(tb: *const QemuPluginTb, idx: usize) -> *mut QemuPluginInsn;
    fn qemu_plugin_insn_vaddr(insn: *const QemuPluginInsn) -> u64;
    fn qemu_plugin_insn_size(insn: *const QemuPluginInsn) -> usize;
    fn qemu_plugin_register_atexit_cb(id: PluginId, cb: UdataCb, userdata: *mut c_void);
    fn qemu_plugin_outs(string: *const c_char);
}

/// The plugin API version this plugin is written for (QEMU 7.2 accepts
/// versions 0 and 1).
#[no_mangle]
pub static qemu_plugin_version: c_int = 1;

static STATE: Mutex<Option<Counter>> = Mutex::new(None);

fn state() -> MutexGuard<'static, Option<Counter>> {
    STATE.lock().unwrap_or_else(PoisonError::into_inner)
}

fn outs(text: &str) {
    if let Ok(c) = CString::new(text) {
        // SAFETY: `c` is a NUL-terminated string that lives across the call;
        // QEMU only reads it.
        unsafe { qemu_plugin_outs(c.as_ptr()) }
    }
}

/// Called by QEMU once, when it loads the plugin. `argv` holds `argc`
/// NUL-terminated strings (the `,`-separated plugin arguments).
#[no_mangle]
pub extern "C" fn qemu_plugin_install(
    id: PluginId,
    _info: *const c_void,
    argc: c_int,
    argv: *const *const c_char,
) -> c_int {
    let mut args = Vec::new();
    for i in 0..usize::try_from(argc).unwrap_or(0) {
        // SAFETY: QEMU passes `argc` valid pointers in `argv`
        // (qemu_plugin_install's contract: "@argv: array of arguments
        // (@argc elements)"); `i < argc`.
        let p = unsafe { *argv.add(i) };
        if p.is_null() {
            continue;
        }
        // SAFETY: each element is a NUL-terminated string that stays valid
        // while the plugin is loaded (ditto: "@argv remains valid
        // throughout the lifetime of the loaded plugin").
        let s = unsafe { CStr::from_ptr(p) };
        args.push(s.to_string_lossy().into_owned());
    }
    let config = match parse_args(args.iter().map(String::as_str)) {
        Ok(c) => c,
        Err(e) => {
            outs(&format!("armcount: {e}\n"));
            return 1;
        }
    };
    *state() = Some(Counter::new(config));
    // SAFETY: `id` is the id QEMU gave this call; the callbacks are
    // `extern "C"` functions with the signatures the API declares.
    unsafe {
        qemu_plugin_register_vcpu_tb_trans_cb(id, on_translate);
        qemu_plugin_register_atexit_cb(id, on_exit, std::ptr::null_mut());
    }
    0
}

/// A block was translated: note its instructions, ask to hear of its runs.
extern "C" fn on_translate(_id: PluginId, tb: *mut QemuPluginTb) {
    // SAFETY: `tb` is the live handle QEMU passes to this callback.
    let n = unsafe { qemu_plugin_tb_n_insns(tb) };
    let mut insns = Vec::with_capacity(n);
    for i in 0..n {
        // SAFETY: `i < n`, the block's instruction count; the handle is
        // valid during this callback, and only read here.
        let (pc, size) = unsafe {
            let insn = qemu_plugin_tb_get_insn(tb, i);
            (qemu_plugin_insn_vaddr(insn), qemu_plugin_insn_size(insn))
        };
        insns.push((pc, u8::try_from(size).unwrap_or(u8::MAX)));
    }
    let handle = match state().as_mut() {
        Some(c) => c.translated(insns),
        None => return,
    };
    // The handle travels as the callback's user data: a number, never
    // dereferenced.
    let udata = std::ptr::without_provenance_mut::<c_void>(handle);
    // SAFETY: `tb` is valid during this callback (registration is only
    // allowed here); `on_run` has the API's signature.
    unsafe { qemu_plugin_register_vcpu_tb_exec_cb(tb, on_run, QEMU_PLUGIN_CB_NO_REGS, udata) }
}

/// A block is about to run.
extern "C" fn on_run(_vcpu: c_uint, udata: *mut c_void) {
    let handle = udata.addr();
    let mut guard = state();
    let Some(c) = guard.as_mut() else { return };
    if c.executed(handle) {
        write_report(c);
    }
}

extern "C" fn on_exit(_id: PluginId, _udata: *mut c_void) {
    if let Some(c) = state().as_mut() {
        write_report(c);
    }
}

fn write_report(c: &mut Counter) {
    let Some(report) = c.take_report() else {
        return;
    };
    outs(&c.summary());
    if let Err(e) = std::fs::write(c.out_path(), report) {
        outs(&format!(
            "armcount: cannot write {}: {e}\n",
            c.out_path().display()
        ));
    }
}
