/*
 * commands.h — the serial protocol (DESIGN.md, "Trigger box").
 *
 * Lines end in "\n" ("\r\n" accepted), at most 64 characters; replies end in "\n".
 * Headers are case-insensitive; SCPI long forms are accepted (FREQuency, OUTPut,
 * SYSTem:ERRor[:NEXT]?, WATCHDOG). Parameters are separated by spaces or a comma.
 *
 *   *IDN?              VTS,TRIGGERBOX,<serial>,<firmware version>
 *   *RST               OK    wave stops (on a whole period), pulses open, defaults
 *   *CLS               OK    clears the error queue
 *   FREQ <hz>          OK    0.1 .. 1000; only while the wave is off
 *   FREQ?              the frequency the hardware makes, e.g. 7.000056000
 *   DUTY <fraction>    OK    0.01 .. 0.99; only while the wave is off
 *   DUTY?              the duty the hardware makes, e.g. 0.500000
 *   OUTP ON|OFF|1|0    OK    OFF finishes the current period, then stops
 *   OUTP?              ON while the wave runs (or finishes its last period), else OFF
 *   PULSE <ch> <ms>    OK    channel 1 (VTS) or 2 (SPECT) closes for 1 .. 10000 ms
 *   PULSE:WIDTH <ms>   OK    the width of the pulses *TRG sends (default 100 ms)
 *   PULSE:WIDTH?       that width
 *   *TRG               OK    wave and both pulses start on the same timer tick
 *   TIME?              device microseconds since boot (64-bit)
 *   EDGES?             <rising edges since start>,<us of the first>,<us of the last>
 *   WDOG <s>           OK    the host watchdog: 0.1 .. 3600 s, 0 = off (10 s at power-up
 *                            and after *RST); at any time
 *   WDOG?              <s>,<OFF|IDLE|ARMED|TRIPPED>,<device us of the cut, 0 if none>
 *   SYST:ERR?          <code>,"<message>" for the oldest error; 0,"No error"
 *
 * A bad line answers "ERR <code> <message>", queues the error and changes nothing.
 *
 * The host watchdog (watchdog.h): every line naming a command above, whatever its reply, is the
 * host's heartbeat. While the output is on and no heartbeat came for the watchdog time, the wave
 * is cut (output low at once, mid-period if need be), OUTP? says OFF, WDOG? says TRIPPED with the
 * device time of the cut until the next start or *RST, and SYST:ERR? gives
 * -310,"Watchdog: host silent, output off".
 */
#ifndef TB_COMMANDS_H
#define TB_COMMANDS_H

void commands_init(void);   /* defaults */
void commands_poll(void);   /* handle every complete line received so far */

#endif
