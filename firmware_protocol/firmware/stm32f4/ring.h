/*
 * ring.h - single-producer single-consumer byte ring between an interrupt and the tick, lock-free:
 * the producer only writes `head`, the consumer only writes `tail`. Size a power of two <= 65536.
 */
#ifndef RING_H
#define RING_H

#include <stddef.h>
#include <stdint.h>

#define RING_SIZE 512u /* bytes; > one tick of traffic at 1 Mbaud and 500 Hz (200 B) */

typedef struct {
    volatile uint16_t head, tail;
    uint8_t data[RING_SIZE];
} ring_t;

static inline size_t ring_used(const ring_t *r) { return (uint16_t)(r->head - r->tail) % RING_SIZE; }
static inline size_t ring_free(const ring_t *r) { return RING_SIZE - 1u - ring_used(r); }

static inline uint8_t ring_put(ring_t *r, uint8_t byte)
{
    uint16_t next = (uint16_t)((r->head + 1u) % RING_SIZE);
    if (next == r->tail) {
        return 0u; /* full */
    }
    r->data[r->head] = byte;
    r->head = next;
    return 1u;
}

/* All of data[0..len) or nothing: 1 when queued, 0 when it did not fit (a whole frame is never cut). */
static inline uint8_t ring_put_all(ring_t *r, const uint8_t *data, size_t len)
{
    size_t i;
    if (ring_free(r) < len) {
        return 0u;
    }
    for (i = 0; i < len; i++) {
        (void)ring_put(r, data[i]);
    }
    return 1u;
}

static inline int ring_get(ring_t *r)
{
    uint16_t t = r->tail;
    int byte;
    if (t == r->head) {
        return -1;
    }
    byte = r->data[t];
    r->tail = (uint16_t)((t + 1u) % RING_SIZE);
    return byte;
}

#endif /* RING_H */
