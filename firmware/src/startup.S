/* Reset entry: stack, copy .data from flash, clear .bss, trap vector, main().
 * The MIK32 boot ROM jumps to the start of SPIFI flash (0x80000000) in SPIFI boot mode;
 * .init is placed first there by link.ld. A trap (illegal instruction, access fault) restarts
 * the firmware from here: the host sees a board reset (new boot nonce). */
    .section .init, "ax"
    .globl _start
_start:
    .option push
    .option norelax
    la   gp, __global_pointer$
    .option pop
    la   sp, __stack_top
    la   t0, trap_entry
    csrw mtvec, t0
    la   a0, __data_load
    la   a1, __data_start
    la   a2, __data_end
1:  bgeu a1, a2, 2f
    lw   t0, 0(a0)
    sw   t0, 0(a1)
    addi a0, a0, 4
    addi a1, a1, 4
    j    1b
2:  la   a1, __bss_start
    la   a2, __bss_end
3:  bgeu a1, a2, 4f
    sw   zero, 0(a1)
    addi a1, a1, 4
    j    3b
4:  call main
5:  j    5b

    .balign 4
trap_entry:
    j    _start
