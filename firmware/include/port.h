/*
 * port.h - the byte link to the host: UART0, the phone over USB (Android Open Accessory), or whichever
 * of the two delivers a valid frame first (board configuration: board_config_t.link, EEPROM).
 *
 * app.c reads received bytes and queues frames through here only, so the deframer, the link watchdog and
 * the failsafe are the same whatever the link. With "first", bytes are taken from one link at a time and
 * the source changes only at a frame boundary (after a 0x00 delimiter) or when the present source has
 * been silent for PORT_SWITCH_MS in the middle of a frame (that partial frame is then a counted bad
 * frame), so the two links' bytes never interleave inside a frame; the first valid frame
 * (port_frame_valid) makes its link the link until the next reset. Until then the board's own frames go
 * out on UART0 only.
 */
#ifndef PORT_H
#define PORT_H

#include <stdint.h>

#include "config.h"
#include "frame.h"

#define PORT_SWITCH_MS 20u
/* Transmit ring room for the Log that says what was not sent (port_poll): any frame's, so the note, whose
 * counts are cleared once it is queued, always fits (160 was one byte short of its longest form). */
#define PORT_NOTE_ROOM FRAME_MAX_WIRE

void port_init(const board_config_t *cfg);
/* The USB stack's pass (main loop). */
void port_poll(void);
/* Next received byte from the active link: 1, or 0 if none waits. */
uint8_t port_read(uint8_t *b);
/* 1 if received bytes wait (also from an interrupt: the link watchdog's stop looks). */
uint8_t port_rx_pending(void);
/* Queue a whole frame: 1, or 0 (nothing queued) if it does not fit. */
uint8_t port_send(const uint8_t *data, uint16_t n);
/* The bytes read last completed a valid frame: with LINK_FIRST, its link becomes the link. */
void port_frame_valid(void);
/* LINK_UART or LINK_USB: the link in use now (LINK_FIRST until one delivered a valid frame). */
uint8_t port_active(void);
/* 1 (and counted) if a Telemetry or Heartbeat made now is not to be queued: the link is USB and no accessory
 * is open. It would be stale by the time a phone is back (never to be shown as live), and it would fill the
 * transmit ring that must still hold the Logs made meanwhile (disconnected, link lost, the state change).
 * Those queued when the phone went away are dropped from the ring (and again at the re-open: usb_link_event),
 * the other frames kept; once an accessory is open, a Log says how many reports were not sent and how many
 * frames were lost (no room while away, or cut at the detach). */
uint8_t port_holds_reports(void);

#endif /* PORT_H */
