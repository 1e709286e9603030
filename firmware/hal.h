/*
 * hal.h: what the firmware core needs from the board, and nothing more (docs/firmware.md).
 *
 * The core never touches a register itself: every access goes through this table, which a
 * port fills in — the real CmodA7 with its AXI register reads and writes, the emulator
 * (fpgaemu.cfirmware) with the cycle-level models of the same blocks. Every function gets
 * the port's `context` first (the emulator runs many boards in one process).
 *
 * Interrupts go the other way: the port calls fw_on_rx, fw_on_tx_done, fw_on_tick,
 * fw_on_alive and fw_on_enable (firmware.h) from its handlers.
 */
#ifndef FW_HAL_H
#define FW_HAL_H

#include <stdbool.h>
#include <stdint.h>

/* The FPGA controller module's input (ActiveController 1 and 3). */
enum { HAL_LOOP_SPEED = 0, HAL_LOOP_CURRENT = 1 };

/* One channel's inputs at the timer tick. */
typedef struct {
    int32_t position;     /* the position counter register, signed 32 bits */
    double speed;         /* the M/T speed measurement, deg/s, in the counting direction */
    double current;       /* the Hall sensor, A */
    bool end_stop;        /* the end-stop switch input */
    bool pwm_enabled;     /* global_enable as the PWM stage sees it */
} hal_sample;

typedef struct {
    /* --- uartcommand and the RX block RAM --- */
    /* Copy `length` content bytes of the frame at byte `start_address` (0 or 200) out of
     * the RX block RAM (word reads, little-endian, on the real board). */
    void (*rx_copy)(void *context, uint16_t start_address, uint16_t length, uint8_t *content);
    /* The read-done register: the half at `start_address` may be reused. */
    void (*rx_ack)(void *context, uint16_t start_address);

    /* --- uartsend and the TX block RAM --- */
    bool (*tx_busy)(void *context);
    /* Write the content into the TX block RAM, set the length register, pulse the send
     * strobe (called only while not busy). `telemetry`/`tag`: a TM and the tag its tick
     * was given (fw_on_tick), for a port that reports timing; otherwise 0. */
    void (*tx_send)(void *context, const uint8_t *content, uint16_t length, bool telemetry,
                    uint64_t tag);
    /* Raise fw_on_tx_done once, at the end of the frame now on the wire. */
    void (*tx_done_interrupt)(void *context);

    /* --- the timers --- */
    void (*timer_start)(void *context);                    /* first tick one period from now */
    void (*timer_set_period_ms)(void *context, uint16_t period_ms);  /* from the next tick on */
    void (*alive_timer_start)(void *context);              /* fw_on_alive every 300 ms */
    uint32_t (*time_us)(void *context);                    /* board time, µs, wraps */

    /* --- per channel (1 = A, 2 = B): PWM, encoder, current sensor --- */
    void (*sample)(void *context, uint8_t channel, hal_sample *out);
    /* The signed duty register (the stage saturates at ±32760). */
    void (*pwm_write)(void *context, uint8_t channel, int32_t duty);
    int16_t (*pwm_read)(void *context, uint8_t channel);
    /* New resolution (pulses per turn) or direction: the count restarts from here. */
    void (*encoder_configure)(void *context, uint8_t channel, uint16_t pulses_per_turn,
                              int8_t direction);

    /* --- the FPGA controller module per channel (ActiveController 1, 3) --- */
    /* Coefficients with 16 fraction bits (kp, ki, kd 48-bit registers, alpha 32-bit). */
    void (*hwpid_configure)(void *context, uint8_t channel, uint8_t loop, int64_t kp,
                            int64_t ki, int64_t kd, int32_t alpha, int32_t limit);
    void (*hwpid_reference)(void *context, uint8_t channel, int32_t reference_q16);
    /* Run from the module's next tick (reset state), or stop and reset. */
    void (*hwpid_run)(void *context, uint8_t channel, bool run);
    bool (*hwpid_saturated)(void *context, uint8_t channel);
} fw_hal;

#endif /* FW_HAL_H */
