/*
 * device.c - hil_mock's whole device tick in C: the plant (furuta_rt/sim/csrc/plant.c), the DAQ's sensor path
 * (noise, ADC and encoder counts) and the firmware core (firmware_protocol/firmware, host HAL), so that a tick is
 * one call and Python only moves bytes between the pseudo-terminal and this library (hil_mock/c_firmware.py).
 *
 * References, held to agreement by tests/test_compiled_plant.py and tests/test_firmware_c.py:
 *   sensor path   furuta_rt.sim.simulator.Simulator.sample, furuta_rt.model.sensors.Calibration.to_counts
 *   device time   hil_mock.firmware.Firmware.advance_plant (the plant runs in device time from the first HELLO)
 *   new session   hil_mock.firmware.Firmware._on_hello (a HELLO to an idle device puts the rig back)
 * The actuator's shaping is not repeated here: the caller tabulates Actuator.torque_terms for each COMMAND count the
 * core outputs (an entry still NaN: the plant waits for it, HIL_SHAPE), and the noise is the simulator's own
 * generator's draws, handed over in blocks.
 *
 * Without a compiled plant (params NULL: a model plant.c does not cover) the caller samples and integrates its
 * plant itself: it sets the readings before hil_tick and runs `pending` substeps after it.
 *
 * hil_lockstep serves the common lockstep round on the pseudo-terminal itself (tick, write, plant, wait for the
 * COMMAND, read it), as hil_mock.device.VirtualDevice.run's loop does round for round, and returns where that loop
 * has something to do (a fault due, a stop or fault request, a signal, a hang-up, a partial write, a new session,
 * the noise block low, an actuator table entry missing, the end of the session, the round budget).
 */
#define _POSIX_C_SOURCE 200809L

#include <errno.h>
#include <math.h>
#include <poll.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "fw_core.h"
#include "plant.h"

#define HIL_OUT_BYTES 4096u /* >= 2 x host_hal.c HOST_TX_BYTES */
#define HIL_OUT_FRAMES 128u /* >= 2 x HOST_TX_FRAMES */
#define HOST_TX_BYTES 2048u /* host_hal.c */
#define HOST_TX_FRAMES 64u

enum {
    HIL_STREAMING = 1,   /* the core is in a session */
    HIL_ANSWERED = 2,    /* a COMMAND answering the last SAMPLE was accepted */
    HIL_NEW_SESSION = 4, /* a HELLO to an idle device: the rig was put back at its initial state */
    HIL_NOISE_LOW = 8,   /* fewer than HIL_NOISE_MARGIN noise draws left: hand over the next block */
    HIL_FRAMES = 16,     /* frames waiting in out */
    HIL_NO_NOISE = 32,   /* a reading found no noise draw left (the caller did not refill): the reading is wrong */
    HIL_SHAPE = 64,      /* the actuator's counts have no entry in the table yet: fill it, then hil_advance */
    HIL_RECONFIGURED = 128, /* a HELLO or CONFIG arrived since the last tick: the lockstep wait is over */
};
#define HIL_NOISE_MARGIN 64u

typedef struct host_device host_device_t; /* host_hal.c */
void host_rx(host_device_t *dev, const uint8_t *data, size_t len);
void host_tick(host_device_t *dev, int16_t theta_adc, int16_t theta_dot_adc, int32_t phi_count, uint8_t encoder_fault);
void host_skip(host_device_t *dev, uint32_t periods);
uint32_t host_take_tx(host_device_t *dev, uint8_t *out, uint16_t *frame_len);
const fw_t *host_core(const host_device_t *dev);
uint32_t host_new_sessions(const host_device_t *dev);
uint32_t host_tx_pending(const host_device_t *dev);

typedef struct {
    host_device_t *fw;              /* the firmware core with its host HAL */
    /* the plant (plant.c) and the rig at its initial state, which a new session starts from */
    const plant_params_t *params;   /* NULL: the caller's plant */
    double *state, *ring;
    int32_t *head;
    int32_t n_delay;
    const double *state0, *ring0;
    const double *actuation;        /* (tau0, damp, command) of COMMAND count c at 3 * (c + 32768); NaN: not yet */
    /* the sensor path */
    const double *noise, *noise0;   /* standard normal draws: the live block, and the first block of the seed */
    uint32_t noise_len, noise_pos, noise0_len;
    double theta_noise, theta_dot_noise, theta_offset;
    double theta_rad_per_count, theta_dot_rad_s_per_count, phi_rad_per_count;
    int32_t adc_min, adc_max, theta_offset_counts, theta_wraps, adc_bits, bessel;
    /* device time -> plant time */
    double substep_hz;
    int64_t plant_start_ns;         /* -1: held at its initial state until the first HELLO */
    int64_t substeps_done, pending;
    uint32_t sessions_seen, replacements;
    uint32_t reconfigured;          /* a HELLO or CONFIG arrived since the last tick (Firmware.reconfigured) */
    /* the core after the last call: its clock, period and actuator counts */
    uint64_t clock_ns;
    uint32_t period_ns;
    int32_t output;
    /* readings of the caller's plant (params NULL) */
    int32_t theta_adc, theta_dot_adc, phi_count;
    /* frames out, in order: bytes and each frame's length; the caller empties it (out_len = out_frames = 0) */
    uint32_t out_len, out_frames;
    uint16_t out_frame_len[HIL_OUT_FRAMES];
    uint8_t out[HIL_OUT_BYTES];
} hil_device_t;

/* hil_lockstep: where the caller's loop goes on (VirtualDevice.run) */
enum {
    HIL_AT_TOP = 0,      /* before the next tick: the loop's top (stop, fault requests, faults due) */
    HIL_AFTER_WRITE = 1, /* the tick's frames went out (`written` of out's bytes; the rest is the caller's to queue),
                          * the plant not advanced yet (HIL_SHAPE, or the pty took only part of the frames) */
    HIL_AWAITING = 2,    /* waiting for the COMMAND until `until_ns` (a request, a signal, a hang-up, an error) */
};
#define HIL_STICKY (HIL_NEW_SESSION | HIL_NOISE_LOW | HIL_NO_NOISE) /* the caller's to handle at the next top */
#define HIL_READ_BYTES 4096 /* hil_mock.device.READ_BYTES */
#define HIL_WAIT_SLICE_NS 50000000LL /* the longest single poll: the stop request is seen at least this often */

typedef struct {
    int32_t fd;                  /* the pty master (non-blocking) */
    uint32_t max_rounds;         /* return at the top after this many rounds */
    volatile int32_t interrupt;  /* set by another thread (a stop or a fault requested): return at the next check */
    int32_t phase;               /* out: HIL_AT_TOP, HIL_AFTER_WRITE or HIL_AWAITING */
    int64_t event_substeps;      /* return at the top once the plant reached this substep (a scheduled fault is due) */
    int64_t timeout_ns;          /* how long a SAMPLE waits for its COMMAND (LOCKSTEP_TIMEOUT_S) */
    /* out */
    int32_t drained;             /* AT_TOP: the last read emptied the pty (no read before the next tick); AWAITING:
                                  * a read of this wait ended short */
    int32_t realtime;            /* AT_TOP: the session ended, the caller paces in real time */
    int32_t error;               /* errno of a failed write the caller must raise (0: none) */
    uint32_t status;             /* the last call's bits, HIL_STICKY bits of every call since entry */
    uint32_t rounds, timed_rounds;  /* ticks, and those that began streaming (timed as the caller times them) */
    uint32_t reads, writes, selects;  /* system calls on the pty */
    uint32_t written;            /* AFTER_WRITE: bytes of out the pty took */
    int64_t round_start_ns, round_clock_ns;  /* the last tick: its start (CLOCK_MONOTONIC), the device clock then */
    int64_t until_ns;            /* AWAITING: when the wait gives up (CLOCK_MONOTONIC) */
    double sum_work_s, worst_work_s;  /* timed ticks: start to the plant advanced */
} hil_serve_t;

size_t hil_device_size(void);
size_t hil_serve_size(void);
uint32_t hil_lockstep(hil_device_t *d, hil_serve_t *s);
uint32_t hil_rx(hil_device_t *d, const uint8_t *data, size_t len);
uint32_t hil_tick(hil_device_t *d, int advance);
uint32_t hil_advance(hil_device_t *d);
uint32_t hil_skip(hil_device_t *d, uint32_t periods);
uint32_t hil_poll(hil_device_t *d);

size_t hil_device_size(void) { return sizeof(hil_device_t); }
size_t hil_serve_size(void) { return sizeof(hil_serve_t); }

/* One quantiser reading: the nearest level, ties up (sensors.count_of). */
static double count_of(double x, double step) { return floor(x / step + 0.5); }

static int32_t adc(const hil_device_t *d, double count)
{
    if (count > d->adc_max) {
        return d->adc_max;
    }
    if (count < d->adc_min) {
        return d->adc_min;
    }
    return (int32_t)count;
}

static double next_noise(hil_device_t *d, uint32_t *status)
{
    if (d->noise_pos >= d->noise_len) {
        *status |= HIL_NO_NOISE;
        return 0.0;
    }
    return d->noise[d->noise_pos++];
}

/* Simulator.sample and Calibration.to_counts: (theta, theta_dot, phi) counts as the DAQ reads them. */
static void sense(hil_device_t *d, int32_t out[3], uint32_t *status)
{
    const double *s = d->state;
    double th = d->bessel ? s[Y] : s[TH] + d->theta_offset;
    double thd = d->bessel ? s[YD] : s[THD];
    if (d->theta_noise != 0.0) {
        th += d->theta_noise * next_noise(d, status);
    }
    if (d->theta_dot_noise != 0.0) {
        thd += d->theta_dot_noise * next_noise(d, status);
    }
    double t = count_of(th, d->theta_rad_per_count);
    int32_t theta;
    if (d->theta_wraps) {
        int64_t span = (int64_t)1 << d->adc_bits, r = ((int64_t)t - d->adc_min) % span;
        theta = (int32_t)((r < 0 ? r + span : r) + d->adc_min);
    } else {
        theta = adc(d, t);
    }
    out[0] = theta + d->theta_offset_counts;
    out[1] = adc(d, count_of(thd, d->theta_dot_rad_s_per_count));
    out[2] = (int32_t)(int64_t)count_of(s[PH], d->phi_rad_per_count);
}

/* Firmware.advance_plant: the plant up to the device clock, driven by the actuator's present counts. */
static uint32_t advance(hil_device_t *d)
{
    const fw_t *fw = host_core(d->fw);
    if (d->plant_start_ns < 0) {
        return 0u;
    }
    int64_t target = (int64_t)nearbyint((double)((int64_t)fw->clock_ns - d->plant_start_ns) * d->substep_hz * 1e-9);
    int64_t n = target - d->substeps_done;
    if (n <= 0) {
        return 0u;
    }
    if (d->params == NULL) {
        d->substeps_done = target;
        d->pending += n;
        return 0u;
    }
    const double *a = d->actuation + 3 * ((int32_t)fw->output + 32768);
    if (isnan(a[0])) {
        return HIL_SHAPE;
    }
    d->substeps_done = target;
    plant_advance(d->params, d->state, d->ring, d->n_delay, d->head, a[0], a[1], a[2], (long)n);
    return 0u;
}

/* After every call: a new session (Firmware._on_hello), frames out, the status bits. */
static uint32_t finish(hil_device_t *d, uint32_t status)
{
    const fw_t *fw = host_core(d->fw);
    uint32_t sessions = host_new_sessions(d->fw);
    if (sessions != d->sessions_seen) {
        d->sessions_seen = sessions;
        if (d->plant_start_ns < 0) {
            d->plant_start_ns = (int64_t)fw->clock_ns;
        } else {
            d->replacements++;
            status |= HIL_NEW_SESSION;
            if (d->params != NULL) {
                memcpy(d->state, d->state0, N_STATE * sizeof *d->state);
                memcpy(d->ring, d->ring0, 3 * (size_t)d->n_delay * sizeof *d->ring);
                *d->head = 0;
                d->noise = d->noise0;
                d->noise_len = d->noise0_len;
                d->noise_pos = 0;
            }
        }
    }
    if (host_tx_pending(d->fw) && d->out_len <= HIL_OUT_BYTES - HOST_TX_BYTES &&
        d->out_frames <= HIL_OUT_FRAMES - HOST_TX_FRAMES) {
        uint32_t n = host_take_tx(d->fw, d->out + d->out_len, d->out_frame_len + d->out_frames);
        for (uint32_t i = 0; i < n; i++) {
            d->out_len += d->out_frame_len[d->out_frames + i];
        }
        d->out_frames += n;
    }
    d->clock_ns = fw->clock_ns;
    d->period_ns = fw->period_ns;
    d->output = fw->output;
    if (d->out_frames) {
        status |= HIL_FRAMES;
    }
    if (d->params != NULL && (d->theta_noise != 0.0 || d->theta_dot_noise != 0.0) &&
        d->noise_len - d->noise_pos < HIL_NOISE_MARGIN) {
        status |= HIL_NOISE_LOW;
    }
    return status | (fw->streaming ? HIL_STREAMING : 0u) | (fw->answered ? HIL_ANSWERED : 0u) |
           (d->reconfigured ? HIL_RECONFIGURED : 0u);
}

/* HELLOs and CONFIGs the core received, from its counters: each HELLO counts a handshake (refused or not), each
 * CONFIG sends a STATUS, and no other received frame sends one (the core's other STATUS are sent by its tick). */
static uint32_t session_frames(const fw_t *fw) { return fw->n.handshakes + fw->n.handshakes_refused + fw->n.status_sent; }

uint32_t hil_rx(hil_device_t *d, const uint8_t *data, size_t len)
{
    uint32_t before = session_frames(host_core(d->fw));
    host_rx(d->fw, data, len);
    if (session_frames(host_core(d->fw)) != before) {
        d->reconfigured = 1u;
    }
    return finish(d, 0u);
}

/* One timer period: the ADCs and the encoder latched (streaming), the core's tick (SAMPLE out, COMMAND applied),
 * then, with `advance`, the plant integrated to the next tick (else hil_advance, after the SAMPLE is written). */
uint32_t hil_tick(hil_device_t *d, int advance_plant)
{
    uint32_t status = 0u;
    int32_t r[3] = {0, 0, 0};
    d->reconfigured = 0u;
    if (host_core(d->fw)->streaming) {
        if (d->params != NULL) {
            sense(d, r, &status);
        } else {
            r[0] = d->theta_adc;
            r[1] = d->theta_dot_adc;
            r[2] = d->phi_count;
        }
    }
    host_tick(d->fw, (int16_t)r[0], (int16_t)r[1], r[2], 0u);
    if (advance_plant) {
        status |= advance(d);
    }
    return finish(d, status);
}

uint32_t hil_advance(hil_device_t *d) { return finish(d, advance(d)); }

/* The timer fired `periods` times without the tick running: the core's clock moves on, the plant with it. */
uint32_t hil_skip(hil_device_t *d, uint32_t periods)
{
    host_skip(d->fw, periods);
    return finish(d, advance(d));
}

/* After a call made on the core directly (host_hangup, host_reboot, ...). */
uint32_t hil_poll(hil_device_t *d) { return finish(d, 0u); }


static int64_t monotonic_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static uint32_t leave(hil_device_t *d, hil_serve_t *s, int32_t phase, uint32_t status, uint32_t sticky)
{
    s->phase = phase;
    s->status = (status & ~(uint32_t)HIL_FRAMES) | sticky | (d->out_frames ? HIL_FRAMES : 0u);
    return (uint32_t)phase;
}

/* VirtualDevice._read during the wait: non-blocking reads into the core until one ends short (the pty emptied) or
 * finds nothing; 0 when the caller must take over (a hang-up's EIO, an error: its own read sees it again). */
static int read_all(hil_device_t *d, hil_serve_t *s, uint32_t *status, uint32_t *sticky, int *drained)
{
    uint8_t buf[HIL_READ_BYTES];
    for (;;) {
        s->reads++;
        ssize_t n = read(s->fd, buf, sizeof buf);
        if (n < 0) {
            return errno == EAGAIN || errno == EWOULDBLOCK;
        }
        if (n == 0) {
            return 1;
        }
        *status = hil_rx(d, buf, (size_t)n);
        *sticky |= *status & HIL_STICKY;
        if (n < HIL_READ_BYTES) {
            *drained = 1;
            return 1;
        }
    }
}

/* Lockstep rounds, each as one pass of VirtualDevice.run's loop with pacing "lockstep", entered at its top with the
 * pty drained, streaming, connected, no frames held back by a link fault, the delay line or a backlog:
 *   tick (SAMPLE out) -> write -> plant advanced -> timed -> wait for the COMMAND answering it (poll, read, rx).
 * Returns the phase the caller resumes at (hil_serve_t.phase), having counted what its loop counts. */
uint32_t hil_lockstep(hil_device_t *d, hil_serve_t *s)
{
    uint32_t status = 0u, sticky = 0u;
    int drained = 1;
    s->rounds = s->timed_rounds = s->reads = s->writes = s->selects = 0u;
    s->written = 0u;
    s->error = 0;
    s->drained = 0;
    s->realtime = 0;
    s->sum_work_s = s->worst_work_s = 0.0;
    struct pollfd pfd = {s->fd, POLLIN, 0};
    for (;;) {
        /* the loop's top */
        if (s->interrupt || !drained || sticky || s->rounds >= s->max_rounds || d->substeps_done >= s->event_substeps) {
            s->drained = drained;
            return leave(d, s, HIL_AT_TOP, status, sticky);
        }
        int64_t start = monotonic_ns();
        int timed = host_core(d->fw)->streaming;
        s->round_start_ns = start;
        s->round_clock_ns = (int64_t)d->clock_ns;
        status = hil_tick(d, 0);
        sticky |= status & HIL_STICKY;
        s->rounds++;
        if (d->out_len) { /* the SAMPLE leaves at the tick */
            s->writes++;
            ssize_t n = write(s->fd, d->out, d->out_len);
            if (n < 0) {
                if (errno == EAGAIN || errno == EWOULDBLOCK) {
                    n = 0;
                } else if (errno == EIO) { /* no host has the port open: the frames are lost, as the caller's */
                    n = (ssize_t)d->out_len;
                } else {
                    s->error = errno;
                    s->written = 0u;
                    return leave(d, s, HIL_AFTER_WRITE, status, sticky);
                }
            }
            if ((uint32_t)n < d->out_len) {
                s->written = (uint32_t)n;
                return leave(d, s, HIL_AFTER_WRITE, status, sticky);
            }
            d->out_len = d->out_frames = 0u;
        }
        status = hil_advance(d);
        sticky |= status & HIL_STICKY;
        if (status & HIL_SHAPE) {
            s->written = 0u;
            return leave(d, s, HIL_AFTER_WRITE, status, sticky);
        }
        if (timed) {
            double work = (double)(monotonic_ns() - start) * 1e-9;
            s->timed_rounds++;
            s->sum_work_s += work;
            if (work > s->worst_work_s) {
                s->worst_work_s = work;
            }
        }
        if (!host_core(d->fw)->streaming) { /* the session ended: real-time pacing from here */
            s->realtime = 1;
            s->drained = 0;
            return leave(d, s, HIL_AT_TOP, status, sticky);
        }
        /* VirtualDevice._await_answer: until the COMMAND, or a HELLO or CONFIG after which none comes */
        int64_t until = monotonic_ns() + s->timeout_ns;
        drained = 0;
        while (!host_core(d->fw)->answered && !d->reconfigured) {
            int64_t remaining = until - monotonic_ns();
            if (s->interrupt) {
                s->until_ns = until;
                s->drained = drained;
                return leave(d, s, HIL_AWAITING, status, sticky);
            }
            if (remaining <= 0) { /* a late command: the next tick reads first */
                s->drained = 0;
                return leave(d, s, HIL_AT_TOP, status, sticky);
            }
            if (remaining > HIL_WAIT_SLICE_NS) {
                remaining = HIL_WAIT_SLICE_NS;
            }
            s->selects++;
            int ready = poll(&pfd, 1, (int)((remaining + 999999) / 1000000)); /* milliseconds, rounded up */
            if (ready < 0 || (ready > 0 && !read_all(d, s, &status, &sticky, &drained))) {
                s->until_ns = until; /* a signal (the caller runs its handlers), a hang-up or an error: its wait */
                s->drained = drained;
                return leave(d, s, HIL_AWAITING, status, sticky);
            }
        }
    }
}
