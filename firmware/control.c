/*
 * control.c: the software PID and fixed-point helpers. Freestanding; double arithmetic in
 * the model's order, compiled without contraction (-ffp-contract=off): a fused
 * multiply-add would round differently from the model.
 */
#include "control.h"

bool fw_finite(double value)
{
    double zero = value - value;
    return zero == zero;
}

int32_t fw_round(double value)
{
    int32_t whole = (int32_t)value; /* towards zero */
    double rest = value - (double)whole; /* exact: the fraction bits of value */
    if (rest > 0.5 || (rest == 0.5 && ((uint32_t)whole & 1u)))
        whole++;
    else if (rest < -0.5 || (rest == -0.5 && ((uint32_t)whole & 1u)))
        whole--;
    return whole;
}

static int64_t fw_round64(double value)
{
    int64_t whole = (int64_t)value;
    double rest = value - (double)whole;
    if (rest > 0.5 || (rest == 0.5 && ((uint64_t)whole & 1u)))
        whole++;
    else if (rest < -0.5 || (rest == -0.5 && ((uint64_t)whole & 1u)))
        whole--;
    return whole;
}

int64_t fw_to_fixed(double value, int bits)
{
    int64_t top = (int64_t)((((uint64_t)1) << (bits - 1)) - 1u);
    double scaled;
    if (!fw_finite(value))
        return 0;
    scaled = value * 65536.0; /* 2^FW_FRACTION_BITS */
    if (scaled >= (double)top)
        return top;
    if (scaled <= -(double)top - 1.0)
        return -top - 1;
    return fw_round64(scaled);
}

void fw_pid_reset(fw_pid *pid)
{
    pid->integral = 0.0;
    pid->derivative = 0.0;
    pid->last_measurement = 0.0;
    pid->has_last = false;
    pid->saturated = false;
}

void fw_pid_init(fw_pid *pid, fw_gains gains, int32_t limit)
{
    pid->gains = gains;
    pid->limit = limit;
    fw_pid_reset(pid);
}

bool fw_pid_at_rest(const fw_pid *pid)
{
    return pid->integral == 0.0 && pid->derivative == 0.0 && !pid->has_last && !pid->saturated;
}

int32_t fw_pid_update(fw_pid *pid, double reference, double measurement, double dt)
{
    double kp, error, proportional, step, candidate, limit;
    if (!(fw_finite(reference) && fw_finite(measurement))) {
        fw_pid_reset(pid);
        return 0;
    }
    kp = pid->gains.kp;
    error = reference - measurement;
    proportional = kp * error;
    if (pid->gains.td > 0.0 && pid->has_last && dt > 0.0) {
        double tf = pid->gains.td / FW_DERIVATIVE_FILTER_N;
        double raw = -kp * pid->gains.td * (measurement - pid->last_measurement) / dt;
        pid->derivative += (raw - pid->derivative) * dt / (tf + dt);
    }
    pid->last_measurement = measurement;
    pid->has_last = true;
    step = kp * dt / pid->gains.ti * error;
    candidate = proportional + pid->integral + step + pid->derivative;
    limit = (double)pid->limit;
    if (candidate > limit) {
        if (step < 0.0)
            pid->integral += step;
        pid->saturated = true;
        return pid->limit;
    }
    if (candidate < -limit) {
        if (step > 0.0)
            pid->integral += step;
        pid->saturated = true;
        return -pid->limit;
    }
    if (candidate != candidate) {
        /* NaN: gains beyond any parameter's range overflowed to inf - inf. */
        fw_pid_reset(pid);
        return 0;
    }
    pid->integral += step;
    pid->saturated = false;
    return fw_round(candidate);
}
