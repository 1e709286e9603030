/*
 * firmware.h: the MicroBlaze firmware core (seed §3.2-3.3), written by hand against the
 * generated fpgalink_protocol.h and the HAL (hal.h). What it does, as the emulator's model
 * of it (src/fpgaemu/firmware.py) does:
 *
 *  - RX interrupt: take the frame out of the RX block RAM, acknowledge the half, check the
 *    wire CRC when it is on, parse; PS (validate, apply, recompute, PA or PN), PG (PA or
 *    PN), RV (references; a non-finite one is refused whole), IQ (IA: the declaration hash
 *    this core was generated from, its version and build, the board's serial); the rest
 *    is counted.
 *  - Timer interrupt every TsTimerPeriod ms: sample, run the controllers, write the PWM,
 *    send TM while GetDataPeriodical = 1.
 *  - E every 300 ms, enabled or not.
 *  - global_enable falling: controllers reset, references cleared, PWM 0.
 *  - ActiveController: 0 software speed PID, 1 the FPGA's speed PID, 2 software current
 *    PID, 3 the FPGA's current PID; a change starts the new controller from rest.
 *
 * All state is in one fw_state, passed to every call (one per board: the emulator runs
 * many). No allocation, no library call; the send queue is fixed (FW_TX_DEPTH frames).
 */
#ifndef FW_FIRMWARE_H
#define FW_FIRMWARE_H

#include <stdbool.h>
#include <stdint.h>

#include "control.h"
#include "fpgalink_protocol.h"
#include "hal.h"

/* The firmware's version and build, as IA reports them (the emulator's model of this core
 * says the same: fpgaemu.firmware.FIRMWARE_VERSION). 1.0 was the seed's, without IQ. A
 * port's build sets FW_BUILD to its commit's first 8 hex digits (-DFW_BUILD=0x1a2b3c4d);
 * 0 is "not set". */
#define FW_VERSION_MAJOR 1u
#define FW_VERSION_MINOR 1u
#define FW_VERSION_PATCH 0u
#ifndef FW_BUILD
#define FW_BUILD 0u
#endif

#define FW_TX_DEPTH 8
#define FW_CHANNELS 2
/* ActiveController values */
enum { FW_SPEED_SW = 0, FW_SPEED_HW = 1, FW_CURRENT_SW = 2, FW_CURRENT_HW = 3 };

/* The current loops' gains are the firmware's, not parameters (SPEC §5 has speed-loop gains
 * only): derived from the motor's electrical model. fw_default_config() gives the seed
 * motor's (24 V, 1 Ω, 1 mH); the emulator passes its model's. */
typedef struct {
    double sw_current_kp;   /* PWM counts per A: a loop gain of 0.5 per tick */
    double hw_current_kp;   /* PWM counts per A: a loop gain of 2 at the module's 10 kHz */
    double electrical_tau;  /* L/R, s: the current loops' integral time */
    uint64_t serial;        /* the board's serial for IA: the FPGA's device DNA (DNA_PORT) */
} fw_config;

typedef struct {
    fw_pid speed_pid;
    fw_pid current_pid;
    double reference;   /* deg/s, or N·m under current control */
    double speed;       /* the last samples */
    double current;
    int32_t position;
} fw_channel;

typedef struct {
    uint32_t messages;
    uint32_t malformed;
    uint32_t unknown;
    uint32_t param_sets;
    uint32_t param_gets;
    uint32_t refusals;
    uint32_t references;
    uint32_t invalid_references;  /* RV refused for a non-finite reference */
    uint32_t telemetry_sent;
    uint32_t telemetry_dropped;   /* the send queue was full */
    uint32_t alive_sent;
    uint32_t crc_failures;        /* frames dropped for a bad wire CRC */
    uint32_t host_in_order;       /* counted messages whose counter was the next expected */
    uint32_t host_out_of_order;
    uint32_t tx_queued;
    uint32_t tx_sent;
    uint32_t tx_dropped;
    uint32_t tx_max_depth;
} fw_stats;

typedef struct {
    uint8_t content[FL_MAX_CONTENT];
    uint16_t length;
    bool telemetry;
    uint64_t tag;
} fw_tx_entry;

typedef struct {
    const fw_hal *hal;
    void *context;
    fw_config config;
    fl_value values[FL_PARAM_SLOTS];   /* every parameter address, in force */
    fw_channel channels[FW_CHANNELS];  /* A, B */
    bool enabled;                       /* global_enable, from its interrupt */
    bool crc_on;                        /* the wire CRC (WireCrc) */
    uint32_t counter;                   /* the next counted message's counter */
    uint32_t host_next;                 /* the host's next expected counter */
    bool host_seen;
    fw_stats stats;
    /* the send queue, a ring; tx_waiting: the TX-done interrupt is asked for */
    fw_tx_entry tx[FW_TX_DEPTH];
    uint8_t tx_head;
    uint8_t tx_count;
    bool tx_waiting;
    uint8_t rx[FL_MAX_CONTENT];
    uint8_t out[FL_MAX_CONTENT];
} fw_state;

fw_config fw_default_config(void);

/* Power-up: every parameter at its default, applied to the hardware. */
void fw_init(fw_state *fw, const fw_hal *hal, void *context, const fw_config *config);
/* An initial value before fw_start (the emulator's --set): 0, or the PN code it would get. */
uint8_t fw_setting(fw_state *fw, uint8_t id, uint8_t channel, uint8_t value_type,
                   uint32_t raw);
/* Configure the controller modules, start the timer and the alive timer. */
void fw_start(fw_state *fw);

/* Interrupt handlers */
void fw_on_rx(fw_state *fw, uint16_t start_address, uint16_t length);
void fw_on_enable(fw_state *fw, bool enabled);
void fw_on_tick(fw_state *fw, uint64_t tag);
void fw_on_tx_done(fw_state *fw);
void fw_on_alive(fw_state *fw);

/* A tick now would change nothing the firmware holds: disabled, no telemetry, controllers
 * at rest, samples zero (the port adds the hardware's part: duty, modules, encoders). */
bool fw_quiescent(const fw_state *fw);

/* The value in force at (id, channel); false for an unknown address. */
bool fw_value(const fw_state *fw, uint8_t id, uint8_t channel, fl_value *value);
int32_t fw_mode(const fw_state *fw, uint8_t channel);

#endif /* FW_FIRMWARE_H */
