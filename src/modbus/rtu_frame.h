/* SPDX-License-Identifier: MIT */
/*
 * rtu_frame.h - Modbus RTU framing by the serial line specification
 * (Modbus over Serial Line V1.02): the CRC-16, the character times, and
 * the line as a conversation (struct rtu_line), which decides which frames
 * on the bus are requests this unit executes. No I/O and no clock of its
 * own: the caller hands in the bytes it read with the time it read them,
 * says when it sends, and asks when a silence is due (mb_rtu.h does it on
 * a real port, tests/test_rtu_frame.c with a fake clock).
 *
 * THE MODEL. A bus is a conversation: a master's request, then at most one
 * response from the unit it addressed, each frame framed by silences of at
 * least 3.5 character times (t3.5). What arrives between two silences is
 * a "chunk"; normally one frame, but a reader that is late (a loaded host,
 * a USB adapter's packet, a pty) may find an exchange and the next request
 * glued in one chunk. Lengths are never guessed: a frame's length comes
 * from what the conversation expects there, and a frame's content is never
 * searched for other frames.
 *
 * Silences are judged from the times of the reads. A port hands bytes
 * over in pieces (a UART's FIFO every 8 characters, further apart than
 * t3.5 at 19200 baud; a USB adapter's packets), so the silence the line
 * is SURE of before some bytes is the time since the last read less their
 * own wire time and the port's delivery (delivery_ns); a reader late for
 * the chunk's silence (a stalled loop) proves none, as the bytes may have
 * come right after the last ones. A pause over t1.5 of that inside a
 * frame discards it. A chunk is judged t3.5 after its
 * last read, except: a frame begun and not whole waits for the port's
 * next piece (RTU_PIECE_CHARS more characters and the delivery), and
 * nothing after it in the chunk is searched (its late pieces); in UNSYNCED
 * every chunk waits that long, so that the silence after it is sure too.
 *
 * States, kept between chunks and walked through a chunk frame by frame:
 *
 *   UNSYNCED  Where the conversation stands is unknown (at start, after a
 *             chunk that did not parse, an overrun, a collision). The
 *             line takes its place again at the first silence it is sure
 *             of (t3.5 beyond the port's delivery: the chunk's start, or
 *             one proven inside the chunk) from which what came parses:
 *               - the rest of the chunk, whole, one frame: a request of
 *                 ours (its function's request length, or any length for
 *                 a function we do not know): EXECUTED -> IDLE; a foreign
 *                 frame of request form -> AWAIT its response; a broadcast
 *                 -> IDLE, never executed; any other frame (a response)
 *                 -> IDLE;
 *               - else its first frame, read as a request (its length
 *                 from its function) or as a response to a request the
 *                 line did not hear (from its own fields: a byte count,
 *                 an exception's 5 bytes), and the walk goes on from
 *                 there as in IDLE or AWAIT;
 *               - anything else: dropped to the next sure silence.
 *             A chunk here, or one that drops something, is judged
 *             only once the line surely fell silent after it (the wait
 *             above), so a frame is taken only with sure silences on both
 *             sides or boundaries the conversation gives.
 *   IDLE      An exchange ended: the next frame is a master's request, of
 *             the length its function code gives (with the byte count
 *             for 15, 16, 20, 21, 23; FC08's return query data, any
 *             length, as the shortest CRC-valid run its response repeats):
 *               - ours: EXECUTED if it is the last frame of its chunk (the
 *                 master waits for our reply; bytes after it mean it did
 *                 not, and the chunk is dropped from there) -> IDLE;
 *               - foreign -> AWAIT (its response's length is now known);
 *               - broadcast -> IDLE, never executed;
 *               - a function whose request length we do not know: taken
 *                 only as the chunk's rest.
 *   AWAIT     A request for unit U went out: the next frame is U's
 *             response, whose length the request gives (5 for an
 *             exception; 05, 06 repeat the request, 15, 16 its address
 *             and count, FC08's return query data all of it), skipped
 *             whole -> IDLE. While a frame of U's unit and function may
 *             still become that response it is never read as anything
 *             else. The master may instead have given up on a silent U:
 *             a frame of another unit, or one of U's that has come whole
 *             with a bad CRC or stopped short, is read as a new request
 *             (as in IDLE), where the last frame ended.
 *
 * TWO READINGS. A foreign frame read as a request that may still become
 * a whole response of another length waits for it (as a frame begun and
 * not whole does). A foreign frame read as a request that is also a whole
 * response of another length (a response whose first bytes were made to
 * pass for a request, with a frame hidden after them; or a request whose
 * bytes happen to be one) is walked both ways: the reading that explains
 * the rest of the chunk is the bus; where both do, only what both would
 * execute is executed; where neither does, it is dropped.
 *
 * A frame that is not what its state expects (wrong unit, function,
 * length or CRC, a pause inside it, or past the chunk's end) drops the
 * chunk from there up to the next sure silence -> UNSYNCED. So a
 * CRC-valid frame hidden in the data of another unit's request or
 * response is never seen: that frame is skipped by its length; where its
 * request was missed, the response is a whole chunk, or the first frame
 * after a sure silence read by its own fields; and a port's piece that
 * happens to start at the hidden frame is no sure silence.
 *
 * NOISE BEFORE A REQUEST. Where that drop would start at a frame boundary
 * (a sure silence, or where the conversation says a frame starts), in a
 * chunk judged once the line surely fell silent after it, and the chunk
 * is 1-3 bytes and then a whole CRC-valid request of ours to its end,
 * the request is executed: bytes that few can be no frame and hold none,
 * and a frame that began at the boundary and went on would have reached
 * the chunk. Not where the request would have begun before the noise
 * ended (read together), nor where it equals our last frame and the
 * noise came within the delivery bound after it (an echo).
 *
 * OUR OWN TRANSMISSIONS. rtu_line_frame_out() and rtu_line_bytes_out()
 * tell the line what we send and when; from them it knows when our last
 * frame leaves the wire (tx_end: the bytes' wire time, none on a pty,
 * which has no wire). A frame byte-equal to our last one is judged by
 * when its first bytes can have come, from the reader's last look at an
 * empty port before them (rtu_line_input_read's 'after_ns'), never from
 * the time of the read (a loop that stalls, an echo in pieces or read by
 * halves, stays what it was):
 *   - local_echo = false, later than the port's delivery bound after
 *     tx_end (delivery_ns: rtu_line_bound_end_ns): the master's, walked
 *     as any frame (a retry after a lost reply, a cyclic rewrite: acted
 *     on and answered, as over TCP);
 *   - local_echo = false, within the bound: where our frame is itself a
 *     request of ours (05, 06: the reply is the request) and it is the
 *     whole chunk, the first one per request executed is answered again
 *     and not acted on again (RTU_EVENT_REPEAT, the 'repeat' hook: a
 *     master that retries at once, or our reply heard back); any other
 *     (a second one, a reply that is no request) is our frame heard back
 *     (RTU_EVENT_ECHO), skipped, and what follows it in the chunk is the
 *     master's next request. Where an echo and the master's repeat are
 *     the same bytes at the same time, answering the master wins: a line
 *     that echoes costs at most one repeated reply per request;
 *   - local_echo = true: the bytes of each frame we send are expected
 *     back first, within RTU_LOCAL_ECHO_WINDOW_NS, and are taken off the
 *     input before any framing, exactly one echo per frame. Where the
 *     input differs (or surely comes later), what matched is input again
 *     with the rest, and the chunk is judged: what the conversation
 *     expects means the adapter gave nothing back (RTU_EVENT_NO_ECHO: a
 *     master's request starts as our reply did, with the unit id and
 *     function); anything else is a collision (RTU_EVENT_COLLISION,
 *     counted), dropped as any chunk that is no frame. An echo that stops
 *     short (the line surely silent after part of it) is a collision too,
 *     and its bytes are dropped: it never costs the next request.
 * Any other frame is the master's, also one that begins before tx_end +
 * t3.5 (a master that keeps no silence of its own: counted out of turn,
 * and served). A frame of an exception's form addressed to us (our own
 * exception reply heard back) is counted and skipped, never a request.
 * The next frame we send may start at rtu_line_tx_ready_ns(): t3.5 after
 * the last one's end.
 *
 * Hooks run from rtu_line_silence() after the line has consumed the
 * chunk: a hook may call rtu_line_frame_out() (a reply sent at once).
 */
#ifndef JAKAGW_RTU_FRAME_H
#define JAKAGW_RTU_FRAME_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

/* Unit id, PDU (at most 253 bytes), CRC. */
#define RTU_MAX_ADU 256
#define RTU_MIN_ADU 4
#define RTU_BROADCAST 0

/* The Modbus CRC-16 (polynomial 0xA001 reflected, initial 0xFFFF), by table. */
/*@ requires \valid_read(data + (0 .. size - 1));
    assigns \nothing;
*/
uint16_t rtu_crc16(const uint8_t *data, size_t size);

/* Does the frame end in the CRC of what precedes it (low byte first)? */
/*@ requires \valid_read(frame + (0 .. size - 1));
    assigns \nothing;
    ensures \result ==> size >= RTU_MIN_ADU;
*/
bool rtu_crc_ok(const uint8_t *frame, size_t size);

/* Appends the CRC to 'size' bytes at 'frame' (room for two more; a frame
 * is at most RTU_MAX_ADU). */
/*@ requires size <= RTU_MAX_ADU - 2 && \valid(frame + (0 .. size + 1));
    assigns frame[size .. size + 1];
    ensures \result == size + 2;
*/
size_t rtu_append_crc(uint8_t *frame, size_t size);

/*
 * The character times for a line, in nanoseconds: 1.5 and 3.5 characters
 * of 1 start bit, 8 data bits, the parity bit and the stop bits; above
 * 19200 baud the fixed 750 us and 1750 us the specification gives.
 */
/*@ requires \valid(t15_ns) && \valid(t35_ns) && \separated(t15_ns, t35_ns);
    assigns *t15_ns, *t35_ns;
*/
void rtu_char_times(unsigned baud, bool parity, unsigned stop_bits, uint32_t *t15_ns,
                    uint32_t *t35_ns);

/* How a length is known. */
enum rtu_length {
    RTU_LENGTH_EXACT,   /* *size is the frame's length */
    RTU_LENGTH_MORE,    /* more bytes are needed to tell; *size is a lower bound */
    RTU_LENGTH_UNKNOWN, /* a function whose form we do not know */
};

/* The facts the proofs of the length functions rest on (make prove): a
 * frame is 'avail' readable bytes; a length told is one of the three
 * answers, and MORE's bound lies beyond what is there. */
/*@ predicate rtu_bytes(uint8_t *d, size_t avail) = \valid_read(d + (0 .. avail - 1));
    predicate rtu_length_told(enum rtu_length how, size_t size, size_t avail) =
        (how == RTU_LENGTH_EXACT || how == RTU_LENGTH_MORE || how == RTU_LENGTH_UNKNOWN) &&
        (how == RTU_LENGTH_MORE ==> size > avail);
*/

/* The length of the request at 'frame' ('avail' bytes there). */
/*@ requires rtu_bytes(frame, avail) && \valid(size);
    assigns *size;
    ensures rtu_length_told(\result, *size, avail);
*/
enum rtu_length rtu_request_length(const uint8_t *frame, size_t avail, size_t *size);

/* The length of the response at 'frame' ('avail' bytes there) to the
 * request 'request' ('request_size' bytes, whole: at least RTU_MIN_ADU;
 * only what it holds is read). */
/*@ requires rtu_bytes(request, request_size) && request_size >= RTU_MIN_ADU;
    requires rtu_bytes(frame, avail) && \valid(size);
    assigns *size;
    ensures rtu_length_told(\result, *size, avail);
*/
enum rtu_length rtu_response_length(const uint8_t *request, size_t request_size,
                                    const uint8_t *frame, size_t avail, size_t *size);

/* local_echo = true: how long after our frame left the wire its one echo
 * is awaited (an adapter's latency timer and a host late to read, with
 * room to spare); nothing of it by then is an adapter that gave nothing
 * back. */
#define RTU_LOCAL_ECHO_WINDOW_NS 1000000000ull
/* A port hands over what it received at least every this many characters
 * (a 16550's FIFO triggers at 14 at most; a USB adapter's lateness is the
 * config's delivery_ns): how long a frame begun but not whole is waited
 * for beyond t3.5, whatever it lacks (garbage that looks like the head of
 * a long frame must not hold the line for 256 characters). */
#define RTU_PIECE_CHARS 16
/* Bytes kept between two silences: several frames glued together. */
#define RTU_LINE_RX_SIZE 1024
#define RTU_LINE_MAX_GAPS 64
/* A gap offset with this bit set is a silence of t3.5 waited past for a
 * frame not yet whole, and kept only if the bytes after it show that the
 * line surely was silent that long (else it was the port's delay): a frame
 * may start there. Without it: a pause > t1.5. A frame across either is
 * discarded. */
#define RTU_GAP_WAITED 0x8000

struct rtu_line_config {
    unsigned unit_id;     /* 1..247 */
    uint32_t t15_ns, t35_ns;
    uint32_t char_ns;     /* one character received */
    uint32_t tx_char_ns;  /* one character we send, on the wire; 0 on a pty */
    uint64_t delivery_ns; /* how late the port may hand over received bytes: a
                           * host-side gap shorter than this is no silence */
    bool local_echo;      /* the adapter gives back what we send */
};

enum rtu_conv { RTU_CONV_UNSYNCED = 0, RTU_CONV_IDLE, RTU_CONV_AWAIT };

struct rtu_line_stats {
    uint64_t frames;         /* frames the conversation explained, every unit */
    uint64_t crc_errors;     /* chunks (or their rest) that were not what was expected */
    uint64_t foreign_frames; /* requests and responses of other units, skipped */
    uint64_t broadcasts;     /* requests for unit 0, never executed */
    uint64_t overruns;       /* chunks longer than the receive buffer */
    uint64_t gap_discards;   /* frames with a pause inside them */
    uint64_t echoes;         /* our frames heard back, skipped */
    uint64_t repeats;        /* our last reply again within the delivery bound: answered again */
    uint64_t exceptions;     /* exception-form frames addressed to us, skipped */
    uint64_t collisions;     /* local echo: our frame came back different */
    uint64_t out_of_turn;    /* chunks begun before t3.5 after our frame, not our echo (served) */
    uint64_t executed;       /* requests of ours handed on */
};

enum rtu_event {
    RTU_EVENT_ECHO,      /* our frame heard back (count in stats) */
    RTU_EVENT_REPEAT,    /* our reply again within the delivery bound: sent again */
    RTU_EVENT_COLLISION, /* local echo differed from what we sent */
    RTU_EVENT_NO_ECHO,   /* local echo: nothing of our frame came back */
    RTU_EVENT_COUNT      /* how many there are; not an event */
};

struct rtu_line_hooks {
    /* A request of ours, to execute and answer: unit id, PDU, CRC. */
    void (*request)(void *user, const uint8_t *frame, size_t size);
    void (*event)(void *user, enum rtu_event event); /* may be NULL */
    /* Send our last frame again, unchanged (nothing is executed); may be
     * NULL. */
    void (*repeat)(void *user);
    void *user;
};

struct rtu_line {
    struct rtu_line_config cfg;
    enum rtu_conv conv;
    uint8_t await_request[RTU_MAX_ADU]; /* AWAIT: the request answered next */
    size_t await_request_size;
    /* The chunk being received. */
    uint8_t rx[RTU_LINE_RX_SIZE];
    size_t rx_used;
    bool chunk_open;   /* bytes came since the last silence */
    bool rx_overrun;   /* more than the buffer: dropped at the silence */
    bool echo_broken;  /* local echo: our frame did not come back whole */
    uint16_t gaps[RTU_LINE_MAX_GAPS];
    size_t gap_count;
    uint64_t first_rx_ns, last_rx_ns;
    uint64_t chunk_after_ns; /* the chunk's first bytes arrived after this */
    bool silence_before;  /* the line surely was silent for t3.5 before it */
    uint64_t judge_at_ns; /* when the chunk's silence is due */
    bool waited;          /* judge_at_ns includes the wait for missing bytes */
    /* What we send. */
    uint64_t tx_end_ns; /* our last frame's last byte off the wire; 0: none yet */
    uint8_t sent[RTU_MAX_ADU];
    size_t sent_size;
    bool repeat_answered; /* the request executed last was answered again once */
    bool echo_pending; /* local echo: sent[echo_at..] still to come back */
    size_t echo_at;
    uint64_t echo_last_ns; /* local echo: when its last bytes were read */
    uint64_t echo_until_ns;
    struct rtu_line_stats stats;
};

/* Sets the line up, UNSYNCED, nothing received or sent. */
void rtu_line_init(struct rtu_line *line, const struct rtu_line_config *cfg);

/* Forgets the chunk, the echo awaited and the conversation (a port
 * opened again); the counters stay. */
void rtu_line_reset(struct rtu_line *line);

/* 'size' bytes read at 'now_ns' (their last byte's arrival, as well as the
 * caller can tell: the time of the read). */
void rtu_line_input(struct rtu_line *line, const uint8_t *data, size_t size, uint64_t now_ns,
                    const struct rtu_line_hooks *hooks);

/* The same, for a reader that knows more: the bytes arrived after
 * 'after_ns' (the last time it found the port empty) and by 'now_ns'. The
 * silences are judged from 'now_ns'; whether the bytes can be our frame
 * heard back (within the delivery bound) from 'after_ns', so a loop late to read
 * an echo cannot make it a request. */
void rtu_line_input_read(struct rtu_line *line, const uint8_t *data, size_t size, uint64_t now_ns,
                         uint64_t after_ns, const struct rtu_line_hooks *hooks);

/* When the caller should call rtu_line_silence(): 0 if no chunk is open. */
uint64_t rtu_line_deadline(const struct rtu_line *line);

/*
 * The time is 'now_ns' and nothing more came: if the chunk's silence has
 * come, the chunk is judged (hooks run) and true is returned; false while
 * a chunk waits (call again at rtu_line_deadline()): a frame begun but not
 * whole, or any chunk while the line does not know where the bus stands,
 * waits RTU_PIECE_CHARS characters and the port's delivery past t3.5.
 */
bool rtu_line_silence(struct rtu_line *line, uint64_t now_ns, const struct rtu_line_hooks *hooks);

/* We start to send 'frame' (a reply; what an echo of it is compared to). */
void rtu_line_frame_out(struct rtu_line *line, const uint8_t *frame, size_t size);

/* 'size' bytes of it were handed to the port at 'now_ns'. */
void rtu_line_bytes_out(struct rtu_line *line, size_t size, uint64_t now_ns);

/* The earliest time our next frame may start: t3.5 after our last one
 * left the wire (0: any time). */
uint64_t rtu_line_tx_ready_ns(const struct rtu_line *line);

/* When a frame equal to our last one stops being possibly ours (0:
 * nothing sent): the port's delivery bound after it left the wire, or with
 * local_echo the end of its echo's wait. A reader that looks at the port
 * then, and finds it empty, lets what comes later be judged as the
 * master's. */
uint64_t rtu_line_bound_end_ns(const struct rtu_line *line);

/* local_echo: when the rest of an echo that came back in part is late
 * (t3.5 beyond the port's delivery after its last bytes; 0: no echo in
 * part). A reader that looks at the port then, and finds it empty, lets
 * the echo be closed as spoiled at the next bytes, which are the
 * master's. */
uint64_t rtu_line_echo_look_ns(const struct rtu_line *line);

#endif
