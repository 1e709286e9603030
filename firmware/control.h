/*
 * control.h: the software PID (seed §3.3) and the fixed-point helpers the FPGA controller
 * module's registers are written with. The same law, in the same order of floating-point
 * operations, as the emulator's model (src/fpgaemu/pid.py, hwcontrol.py), so the two give
 * the same duty to the bit.
 */
#ifndef FW_CONTROL_H
#define FW_CONTROL_H

#include <stdbool.h>
#include <stdint.h>

#define FW_DERIVATIVE_FILTER_N 10.0
#define FW_FRACTION_BITS 16
#define FW_COEFFICIENT_BITS 48

typedef struct {
    double kp;  /* PWM counts per deg/s (per A in a current loop) */
    double ti;  /* s */
    double td;  /* s */
} fw_gains;

/* u = Kp·(e + (1/Ti)∫e dt + Td·de/dt): derivative on the measurement, filtered (Td/N);
 * output clamped to ±limit; conditional integration while clamped; a non-finite input
 * outputs 0 and resets. */
typedef struct {
    fw_gains gains;
    int32_t limit;
    double integral;
    double derivative;
    double last_measurement;
    bool has_last;
    bool saturated;
} fw_pid;

void fw_pid_init(fw_pid *pid, fw_gains gains, int32_t limit);
void fw_pid_reset(fw_pid *pid);
bool fw_pid_at_rest(const fw_pid *pid);
int32_t fw_pid_update(fw_pid *pid, double reference, double measurement, double dt);

bool fw_finite(double value);
/* Round half to even, as Python's round() (|x| < 2^31). */
int32_t fw_round(double value);
/* A register value with 16 fraction bits, saturated to `bits` (non-finite: 0). */
int64_t fw_to_fixed(double value, int bits);

#endif /* FW_CONTROL_H */
