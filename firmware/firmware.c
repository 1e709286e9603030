/*
 * firmware.c: the firmware core. See firmware.h for what it does; docs/firmware.md for the
 * porting checklist. Every behaviour here has its counterpart in src/fpgaemu/firmware.py,
 * and the emulator's test suite runs against both.
 */
#include "firmware.h"

#define FW_HW_DT (10000.0 / 100000000.0) /* the FPGA module's period: 10 kHz */
#define FW_CYCLES_PER_MS 100000u

/* --- small helpers ------------------------------------------------------------------------ */

static fw_channel *channel_of(fw_state *fw, uint8_t channel)
{
    return &fw->channels[channel - 1u];
}

static fl_value value_at(const fw_state *fw, uint8_t id, uint8_t channel)
{
    const fl_param_info *p = fl_param_find(id);
    return fw->values[fl_param_slot(p, channel)];
}

static double float_at(const fw_state *fw, uint8_t id, uint8_t channel)
{
    return (double)value_at(fw, id, channel).f;
}

static int32_t int_at(const fw_state *fw, uint8_t id, uint8_t channel)
{
    return value_at(fw, id, channel).i;
}

int32_t fw_mode(const fw_state *fw, uint8_t channel)
{
    return int_at(fw, FL_PARAM_ACTIVE_CONTROLLER, channel);
}

static bool hardware_mode(int32_t mode)
{
    return mode == FW_SPEED_HW || mode == FW_CURRENT_HW;
}

static fw_gains speed_gains(const fw_state *fw, uint8_t channel)
{
    fw_gains gains;
    gains.kp = float_at(fw, FL_PARAM_KP_WHEEL_PID, channel);
    gains.ti = float_at(fw, FL_PARAM_TI_WHEEL_PID, channel);
    gains.td = float_at(fw, FL_PARAM_TD_WHEEL_PID, channel);
    return gains;
}

fw_config fw_default_config(void)
{
    /* The seed's motor: 24 V, 1 Ω, 1 mH; the duty's full scale is 32760. */
    const double amps_per_count = 24.0 / 1.0 / 32760.0;
    fw_config config;
    config.sw_current_kp = 0.5 / amps_per_count;
    config.hw_current_kp = 2.0 / amps_per_count;
    config.electrical_tau = 1e-3 / 1.0;
    config.serial = 0u;  /* the port reads the device DNA and sets it before fw_init */
    return config;
}

/* --- sending --------------------------------------------------------------------------- */

static void tx_start(fw_state *fw, const fw_tx_entry *entry)
{
    fw->hal->tx_send(fw->context, entry->content, entry->length, entry->telemetry, entry->tag);
    fw->stats.tx_sent++;
}

static void tx_wait(fw_state *fw)
{
    if (!fw->tx_waiting) {
        fw->tx_waiting = true;
        fw->hal->tx_done_interrupt(fw->context);
    }
}

/* Send at once while uartsend is idle, else queue (bounded); false when the queue was full. */
static bool tx_send(fw_state *fw, const uint8_t *content, uint16_t length, bool telemetry,
                    uint64_t tag)
{
    fw_tx_entry *entry;
    uint16_t i;
    if (fw->tx_count == 0u && !fw->hal->tx_busy(fw->context)) {
        fw->hal->tx_send(fw->context, content, length, telemetry, tag);
        fw->stats.tx_sent++;
        return true;
    }
    if (fw->tx_count >= FW_TX_DEPTH) {
        fw->stats.tx_dropped++;
        return false;
    }
    entry = &fw->tx[(fw->tx_head + fw->tx_count) % FW_TX_DEPTH];
    for (i = 0u; i < length; i++)
        entry->content[i] = content[i];
    entry->length = length;
    entry->telemetry = telemetry;
    entry->tag = tag;
    fw->tx_count++;
    fw->stats.tx_queued++;
    if (fw->tx_count > fw->stats.tx_max_depth)
        fw->stats.tx_max_depth = fw->tx_count;
    tx_wait(fw);
    return true;
}

void fw_on_tx_done(fw_state *fw)
{
    fw->tx_waiting = false;
    if (fw->tx_count != 0u && !fw->hal->tx_busy(fw->context)) {
        tx_start(fw, &fw->tx[fw->tx_head]);
        fw->tx_head = (uint8_t)((fw->tx_head + 1u) % FW_TX_DEPTH);
        fw->tx_count--;
    }
    if (fw->tx_count != 0u)
        tx_wait(fw);
}

static uint32_t take_counter(fw_state *fw)
{
    uint32_t value = fw->counter;
    fw->counter = value + 1u == FL_COUNTER_MODULUS ? 0u : value + 1u;
    return value;
}

/* A counted message: its CRC when the wire CRC is on, then send or queue. */
static bool send_counted(fw_state *fw, size_t length, bool telemetry, uint64_t tag)
{
    if (fw->crc_on)
        length = fl_crc_append(fw->out, length);
    return tx_send(fw, fw->out, (uint16_t)length, telemetry, tag);
}

static void refuse(fw_state *fw, uint8_t id, uint8_t channel, uint8_t error)
{
    fl_pn_t pn;
    fw->stats.refusals++;
    pn.param_id = id;
    pn.channel = channel;
    pn.error = error;
    send_counted(fw, fl_encode_pn(fw->out, take_counter(fw), &pn), false, 0u);
}

static void acknowledge(fw_state *fw, const fl_param_info *p, uint8_t channel)
{
    fl_pa_t pa;
    pa.param_id = p->id;
    pa.channel = channel;
    pa.value_type = p->type;
    pa.value = fw->values[fl_param_slot(p, channel)];
    send_counted(fw, fl_encode_pa(fw->out, take_counter(fw), &pa), false, 0u);
}

void fw_on_alive(fw_state *fw)
{
    static const uint8_t alive[1] = { (uint8_t)'E' };
    if (tx_send(fw, alive, 1u, false, 0u))
        fw->stats.alive_sent++;
}

/* --- the controllers ------------------------------------------------------------------- */

static double current_reference(const fw_state *fw, uint8_t channel)
{
    const fw_channel *ch = &fw->channels[channel - 1u];
    return ch->reference / float_at(fw, FL_PARAM_TORQUE_COEF, channel);
}

static void write_hardware_reference(fw_state *fw, uint8_t channel)
{
    double reference = fw_mode(fw, channel) == FW_CURRENT_HW ? current_reference(fw, channel)
                                                             : channel_of(fw, channel)->reference;
    fw->hal->hwpid_reference(fw->context, channel, (int32_t)fw_to_fixed(reference, 32));
}

/* The module's coefficient registers from standard-form gains, as a System Generator
 * design takes them: kp = Kp, ki = Kp·dt/Ti, kd = Kp·Td/dt, alpha = dt/(Td/N + dt). */
static void configure_hardware(fw_state *fw, uint8_t channel)
{
    int32_t limit = int_at(fw, FL_PARAM_MAX_CONTROL_SIGNAL, channel);
    fw_gains gains;
    uint8_t loop;
    double alpha;
    if (fw_mode(fw, channel) == FW_CURRENT_HW) {
        gains.kp = fw->config.hw_current_kp;
        gains.ti = fw->config.electrical_tau;
        gains.td = 0.0;
        loop = HAL_LOOP_CURRENT;
    } else {
        gains = speed_gains(fw, channel);
        loop = HAL_LOOP_SPEED;
    }
    alpha = gains.td > 0.0 ? FW_HW_DT / (gains.td / FW_DERIVATIVE_FILTER_N + FW_HW_DT) : 1.0;
    fw->hal->hwpid_configure(fw->context, channel, loop,
                             fw_to_fixed(gains.kp, FW_COEFFICIENT_BITS),
                             fw_to_fixed(gains.kp * FW_HW_DT / gains.ti, FW_COEFFICIENT_BITS),
                             fw_to_fixed(gains.kp * gains.td / FW_HW_DT, FW_COEFFICIENT_BITS),
                             (int32_t)fw_to_fixed(alpha, 32), limit);
    write_hardware_reference(fw, channel);
}

/* A new controller for the channel: from rest, at reference 0, also while enabled. */
static void change_controller(fw_state *fw, uint8_t channel)
{
    fw_channel *ch = channel_of(fw, channel);
    ch->reference = 0.0;
    fw_pid_reset(&ch->speed_pid);
    fw_pid_reset(&ch->current_pid);
    fw->hal->hwpid_run(fw->context, channel, false);
    configure_hardware(fw, channel);
    if (fw->enabled && hardware_mode(fw_mode(fw, channel)))
        fw->hal->hwpid_run(fw->context, channel, true);
}

/* Store and recompute whatever depends on the parameter. */
static void apply(fw_state *fw, const fl_param_info *p, uint8_t channel, fl_value value)
{
    fw->values[fl_param_slot(p, channel)] = value;
    if (p->id == FL_PARAM_TS_TIMER_PERIOD) {
        fw->hal->timer_set_period_ms(fw->context, (uint16_t)value.i);
    } else if (p->id == FL_PARAM_WIRE_CRC) {
        /* Before the PA goes out: the confirmation is the first message in the new form. */
        fw->crc_on = value.i == 1;
    } else if (p->scope == FL_SCOPE_CHANNEL) {
        fw_channel *ch = channel_of(fw, channel);
        switch (p->id) {
        case FL_PARAM_ACTIVE_CONTROLLER:
            change_controller(fw, channel);
            break;
        case FL_PARAM_MAX_CONTROL_SIGNAL:
            ch->speed_pid.limit = ch->current_pid.limit = value.i;
            configure_hardware(fw, channel);
            break;
        case FL_PARAM_INC_SENZ_RES:
        case FL_PARAM_INC_SENZ_COUNT_DIRECTION:
            fw->hal->encoder_configure(fw->context, channel,
                                       (uint16_t)int_at(fw, FL_PARAM_INC_SENZ_RES, channel),
                                       (int8_t)int_at(fw, FL_PARAM_INC_SENZ_COUNT_DIRECTION,
                                                      channel));
            break;
        case FL_PARAM_KP_WHEEL_PID:
        case FL_PARAM_TI_WHEEL_PID:
        case FL_PARAM_TD_WHEEL_PID:
            ch->speed_pid.gains = speed_gains(fw, channel);
            configure_hardware(fw, channel);
            break;
        case FL_PARAM_TORQUE_COEF:
            write_hardware_reference(fw, channel);
            break;
        default:
            break;
        }
    }
}

/* --- power-up -------------------------------------------------------------------------- */

void fw_init(fw_state *fw, const fw_hal *hal, void *context, const fw_config *config)
{
    uint8_t c;
    size_t i;
    uint32_t *stat = (uint32_t *)&fw->stats;
    fw->hal = hal;
    fw->context = context;
    fw->config = *config;
    fw->enabled = false;
    fw->crc_on = false;
    fw->counter = 0u;
    fw->host_next = 0u;
    fw->host_seen = false;
    fw->tx_head = 0u;
    fw->tx_count = 0u;
    fw->tx_waiting = false;
    for (i = 0u; i < sizeof fw->stats / sizeof(uint32_t); i++)
        stat[i] = 0u;
    for (i = 0u; i < FL_PARAM_COUNT; i++) {
        const fl_param_info *p = &fl_params[i];
        fw->values[p->slot] = p->power_up;
        if (p->scope == FL_SCOPE_CHANNEL)
            fw->values[p->slot + 1u] = p->power_up;
    }
    for (c = 1u; c <= FW_CHANNELS; c++) {
        fw_channel *ch = channel_of(fw, c);
        fw_gains current;
        current.kp = config->sw_current_kp;
        current.ti = config->electrical_tau;
        current.td = 0.0;
        fw_pid_init(&ch->speed_pid, speed_gains(fw, c), 32760);
        fw_pid_init(&ch->current_pid, current, 32760);
        ch->reference = 0.0;
        ch->speed = 0.0;
        ch->current = 0.0;
        ch->position = 0;
    }
    /* Every default applied to the hardware, in table order. */
    for (i = 0u; i < FL_PARAM_COUNT; i++) {
        const fl_param_info *p = &fl_params[i];
        if (p->scope == FL_SCOPE_BOARD) {
            apply(fw, p, FL_CHANNEL_BOARD, p->power_up);
        } else {
            apply(fw, p, FL_CHANNEL_A, p->power_up);
            apply(fw, p, FL_CHANNEL_B, p->power_up);
        }
    }
}

uint8_t fw_setting(fw_state *fw, uint8_t id, uint8_t channel, uint8_t value_type,
                   uint32_t raw)
{
    fl_value value;
    uint8_t error;
    value.raw = raw;
    error = fl_param_check_set(id, channel, value_type, value);
    if (error == 0u)
        apply(fw, fl_param_find(id), channel, value);
    return error;
}

void fw_start(fw_state *fw)
{
    uint8_t c;
    for (c = 1u; c <= FW_CHANNELS; c++)
        configure_hardware(fw, c);
    fw->hal->timer_start(fw->context);
    fw->hal->alive_timer_start(fw->context);
}

bool fw_value(const fw_state *fw, uint8_t id, uint8_t channel, fl_value *value)
{
    const fl_param_info *p = fl_param_find(id);
    int slot = p ? fl_param_slot(p, channel) : -1;
    if (slot < 0)
        return false;
    *value = fw->values[slot];
    return true;
}

/* --- receiving ------------------------------------------------------------------------- */

static void handle_set(fw_state *fw, const fl_ps_t *ps)
{
    uint8_t error = fl_param_check_set(ps->param_id, ps->channel, ps->value_type, ps->value);
    const fl_param_info *p;
    if (error != 0u) {
        refuse(fw, ps->param_id, ps->channel, error);
        return;
    }
    p = fl_param_find(ps->param_id);
    apply(fw, p, ps->channel, ps->value);
    acknowledge(fw, p, ps->channel);
}

static void handle_get(fw_state *fw, const fl_pg_t *pg)
{
    uint8_t error = fl_param_check_get(pg->param_id, pg->channel);
    if (error != 0u)
        refuse(fw, pg->param_id, pg->channel, error);
    else
        acknowledge(fw, fl_param_find(pg->param_id), pg->channel);
}

static void handle_references(fw_state *fw, const fl_rv_t *rv)
{
    uint8_t c;
    /* A non-finite reference is refused whole: nothing a broken host sends may reach a
     * controller. */
    if (!fw_finite((double)rv->ref_a) || !fw_finite((double)rv->ref_b)) {
        fw->stats.invalid_references++;
        return;
    }
    fw->stats.references++;
    fw->channels[0].reference = (double)rv->ref_a;
    fw->channels[1].reference = (double)rv->ref_b;
    for (c = 1u; c <= FW_CHANNELS; c++)
        if (hardware_mode(fw_mode(fw, c)))
            write_hardware_reference(fw, c);
}

static void answer_identity(fw_state *fw, const fl_iq_t *iq)
{
    fl_ia_t ia;
    ia.nonce = iq->nonce;
    ia.declarations = FL_DECLARATIONS_HASH;
    ia.firmware_major = FW_VERSION_MAJOR;
    ia.firmware_minor = FW_VERSION_MINOR;
    ia.firmware_patch = FW_VERSION_PATCH;
    ia.build = FW_BUILD;
    ia.serial = fw->config.serial;
    send_counted(fw, fl_encode_ia(fw->out, take_counter(fw), &ia), false, 0u);
}

static void observe_host_counter(fw_state *fw, uint32_t counter)
{
    if (fw->host_seen && counter == fw->host_next)
        fw->stats.host_in_order++;
    else if (fw->host_seen)
        fw->stats.host_out_of_order++;
    fw->host_seen = true;
    fw->host_next = counter + 1u == FL_COUNTER_MODULUS ? 0u : counter + 1u;
}

void fw_on_rx(fw_state *fw, uint16_t start_address, uint16_t length)
{
    fl_message message;
    int usable;
    if (length > FL_MAX_CONTENT)
        length = FL_MAX_CONTENT;
    fw->hal->rx_copy(fw->context, start_address, length, fw->rx);
    fw->hal->rx_ack(fw->context, start_address);
    usable = fl_crc_board_receive(fw->crc_on, fw->rx, length);
    if (usable < 0) {
        fw->stats.crc_failures++;
        return;
    }
    fl_parse(fw->rx, (size_t)usable, &message);
    fw->stats.messages++;
    if (message.kind >= FL_MSG_PS || message.kind == FL_MSG_COUNTED)
        observe_host_counter(fw, message.counter);
    switch (message.kind) {
    case FL_MSG_RV:
        handle_references(fw, &message.body.rv);
        break;
    case FL_MSG_PS:
        fw->stats.param_sets++;
        handle_set(fw, &message.body.ps);
        break;
    case FL_MSG_PG:
        fw->stats.param_gets++;
        handle_get(fw, &message.body.pg);
        break;
    case FL_MSG_IQ:
        answer_identity(fw, &message.body.iq);
        break;
    case FL_MSG_MALFORMED:
        fw->stats.malformed++;
        break;
    default:
        fw->stats.unknown++;
        break;
    }
}

void fw_on_enable(fw_state *fw, bool enabled)
{
    uint8_t c;
    fw->enabled = enabled;
    for (c = 1u; c <= FW_CHANNELS; c++) {
        fw_channel *ch = channel_of(fw, c);
        if (enabled) {
            if (hardware_mode(fw_mode(fw, c)))
                fw->hal->hwpid_run(fw->context, c, true);
            continue;
        }
        fw->hal->hwpid_run(fw->context, c, false);
        fw_pid_reset(&ch->speed_pid);
        fw_pid_reset(&ch->current_pid);
        ch->reference = 0.0;
        write_hardware_reference(fw, c);
        fw->hal->pwm_write(fw->context, c, 0);
    }
}

/* --- the timer tick -------------------------------------------------------------------- */

void fw_on_tick(fw_state *fw, uint64_t tag)
{
    int32_t period_ms = int_at(fw, FL_PARAM_TS_TIMER_PERIOD, FL_CHANNEL_BOARD);
    double dt = (double)((uint32_t)period_ms * FW_CYCLES_PER_MS) / 100000000.0;
    bool telemetry = int_at(fw, FL_PARAM_GET_DATA_PERIODICAL, FL_CHANNEL_BOARD) == 1;
    fl_tm_t tm;
    uint8_t c;
    for (c = 1u; c <= FW_CHANNELS; c++) {
        fw_channel *ch = channel_of(fw, c);
        fl_tm_a_t *out = c == FL_CHANNEL_A ? &tm.a : &tm.b;
        int32_t mode = fw_mode(fw, c);
        hal_sample sample;
        bool saturated;
        fw->hal->sample(fw->context, c, &sample);
        ch->speed = sample.speed;
        ch->position = sample.position;
        ch->current = sample.current;
        if (!fw->enabled) {
            fw_pid_reset(&ch->speed_pid);
            fw_pid_reset(&ch->current_pid);
            fw->hal->pwm_write(fw->context, c, 0);
            saturated = false;
        } else if (mode == FW_SPEED_SW) {
            fw->hal->pwm_write(fw->context, c,
                               fw_pid_update(&ch->speed_pid, ch->reference, ch->speed, dt));
            saturated = ch->speed_pid.saturated;
        } else if (mode == FW_CURRENT_SW) {
            fw_pid *pid = &ch->current_pid;
            /* Ti no shorter than the period: the loop stays stable at any timer period. */
            double ti = fw->config.electrical_tau > dt ? fw->config.electrical_tau : dt;
            if (pid->gains.ti != ti) {
                pid->gains.kp = fw->config.sw_current_kp;
                pid->gains.ti = ti;
                pid->gains.td = 0.0;
            }
            fw->hal->pwm_write(fw->context, c,
                               fw_pid_update(pid, current_reference(fw, c), ch->current, dt));
            saturated = pid->saturated;
        } else {
            /* the FPGA module runs the loop; the software only reports */
            saturated = fw->hal->hwpid_saturated(fw->context, c);
        }
        if (telemetry) {
            uint8_t flags = sample.pwm_enabled ? FL_TM_FLAG_ENABLE : 0u;
            if (sample.end_stop)
                flags |= FL_TM_FLAG_END_STOP;
            if (saturated)
                flags |= FL_TM_FLAG_SATURATED;
            out->position = ch->position;
            out->speed = (float)ch->speed;
            out->current = (float)ch->current;
            out->pwm = sample.pwm_enabled ? fw->hal->pwm_read(fw->context, c) : 0;
            out->reference = (float)ch->reference;
            out->flags = flags;
        }
    }
    if (telemetry) {
        tm.t_us = fw->hal->time_us(fw->context);
        if (send_counted(fw, fl_encode_tm(fw->out, take_counter(fw), &tm), true, tag))
            fw->stats.telemetry_sent++;
        else
            fw->stats.telemetry_dropped++;
    }
}

bool fw_quiescent(const fw_state *fw)
{
    uint8_t c;
    if (fw->enabled || int_at(fw, FL_PARAM_GET_DATA_PERIODICAL, FL_CHANNEL_BOARD) == 1)
        return false;
    for (c = 0u; c < FW_CHANNELS; c++) {
        const fw_channel *ch = &fw->channels[c];
        if (!fw_pid_at_rest(&ch->speed_pid) || !fw_pid_at_rest(&ch->current_pid)
            || ch->speed != 0.0 || ch->current != 0.0)
            return false;
    }
    return true;
}
