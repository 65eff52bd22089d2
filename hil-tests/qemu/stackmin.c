/* QEMU TCG plugin: lowest stack pointer seen (stack high-water mark).
 *   -plugin ./libstackmin.so[,top=0x20020000][,arm=0x0800abcd]
 * With `arm`, tracking starts once code at that address has run (e.g. the first filter step,
 * to see the steady state without the one-time initialisation).
 * Reads SP at the start of every executed translation block (a function's frame is in place
 * by the first branch after its prologue) and prints each new minimum on stderr, so the
 * figure survives QEMU being killed. used = top - min.
 * Build: gcc -O2 -shared -fPIC -I<qemu-src>/include/qemu $(pkg-config --cflags glib-2.0) stackmin.c
 */
#include <inttypes.h>
#include <stdio.h>
#include <string.h>
#include <glib.h>
#include <qemu-plugin.h>

QEMU_PLUGIN_EXPORT int qemu_plugin_version = QEMU_PLUGIN_VERSION;

static struct qemu_plugin_register *sp_reg;
static uint64_t top = 0x20020000, min_sp = UINT64_MAX, arm_addr;
static int armed = 1;

static void vcpu_init(qemu_plugin_id_t id, unsigned int vcpu) {
    g_autoptr(GArray) regs = qemu_plugin_get_registers();
    for (guint i = 0; i < regs->len; i++) {
        qemu_plugin_reg_descriptor *d = &g_array_index(regs, qemu_plugin_reg_descriptor, i);
        if (!strcmp(d->name, "sp") || !strcmp(d->name, "r13")) sp_reg = d->handle;
    }
    if (!sp_reg) fprintf(stderr, "stackmin: no sp register\n");
}

static void on_arm(unsigned int vcpu, void *ud) { armed = 1; }

static void on_tb(unsigned int vcpu, void *ud) {
    if (!sp_reg || !armed) return;
    g_autoptr(GByteArray) buf = g_byte_array_new();
    if (qemu_plugin_read_register(sp_reg, buf) < 4) return;
    uint32_t sp;
    memcpy(&sp, buf->data, 4);
    /* only the main RAM stack (exclude the reset value 0 before the vector table loads) */
    if (sp >= 0x20000000 && sp < top && sp < min_sp) {
        min_sp = sp;
        fprintf(stderr, "stackmin: sp_min=0x%08" PRIx64 " used=%" PRIu64 " bytes\n", min_sp, top - min_sp);
        fflush(stderr);
    }
}

static void tb_trans(qemu_plugin_id_t id, struct qemu_plugin_tb *tb) {
    if (arm_addr && qemu_plugin_tb_vaddr(tb) == arm_addr)
        qemu_plugin_register_vcpu_tb_exec_cb(tb, on_arm, QEMU_PLUGIN_CB_NO_REGS, NULL);
    qemu_plugin_register_vcpu_tb_exec_cb(tb, on_tb, QEMU_PLUGIN_CB_R_REGS, NULL);
}

QEMU_PLUGIN_EXPORT int qemu_plugin_install(qemu_plugin_id_t id, const qemu_info_t *info,
                                           int argc, char **argv) {
    for (int i = 0; i < argc; i++) {
        if (g_str_has_prefix(argv[i], "top=")) top = g_ascii_strtoull(argv[i] + 4, NULL, 0);
        else if (g_str_has_prefix(argv[i], "arm=")) { arm_addr = g_ascii_strtoull(argv[i] + 4, NULL, 0); armed = 0; }
        else { fprintf(stderr, "stackmin: bad arg %s\n", argv[i]); return -1; }
    }
    qemu_plugin_register_vcpu_init_cb(id, vcpu_init);
    qemu_plugin_register_vcpu_tb_trans_cb(id, tb_trans);
    return 0;
}
