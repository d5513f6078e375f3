/*
 * tbsim — firmware-in-the-loop harness for the trigger box.
 *
 * Runs the real firmware ELF on simavr (ATmega328P, 16 MHz) in real time and
 *   - exposes UART0 as a pseudo-terminal (uart_pty from libsimavrparts) that a host
 *     program opens with pyserial, exactly as it would open the USB serial of a real box;
 *   - logs every change of the output pins (OC1A = square wave, CH1 and CH2 = start
 *     pulses) with the emulated cycle count, one flushed line per edge:
 *         <cycle> <pin> <0|1>
 *     and, unless --no-uart-log, every byte on the serial line:
 *         <cycle> RX <hex>     host -> device, the cycle the byte was handed to the UART
 *         <cycle> TX <hex>     device -> host, the cycle the firmware wrote UDR0
 *     Lines starting with '#' are comments; one of them, written as the emulation starts,
 *     anchors emulated cycles to host time (see the pacing below):
 *         # t0 <cycle> <CLOCK_REALTIME epoch s> <CLOCK_MONOTONIC s> <speed>
 *
 * Usage: tbsim --edges FILE [--pty-file FILE] [--status FILE] [--speed X]
 *              [--mcu NAME] [--freq HZ] [--no-uart-log] FIRMWARE.elf
 *
 * Pacing: emulated cycles are kept in step with the wall clock (times --speed; 0 runs
 * as fast as the host can), to about 0.2 ms while the host gives us the CPU; after a
 * stall (the host busy elsewhere) the emulation runs flat out until it has caught up.
 * simavr skips the firmware's sleep up to the next timer event; we replace its own sleep
 * callback (which would usleep on its own account) and sleep here instead, whenever the
 * emulation is ahead of the wall clock.
 *
 * Serial, host -> device: uart_pty's thread reads the pty into its FIFO. We do NOT use
 * uart_pty_connect(): it ties delivery to the UART's XON/XOFF signals (bursts into the
 * UART's 64-byte FIFO, from a 1 kHz flush timer) and makes a fixed /tmp/simavr-uart0
 * symlink that parallel runs would fight over. Instead a cycle timer on the simulation
 * thread takes one byte per 8N1 byte time at 115200 baud (1389 cycles) and raises it into
 * the UART; the UART's XOFF (input FIFO full) holds the pace back so nothing is dropped.
 * Device -> host: each byte the firmware writes to UDR0 (the UART paces them) is written
 * to the pty master at once from the simulation thread: uart_pty's thread would notice it
 * only when its 0.5 ms select() times out, which skews round-trip timing.
 *
 * The process exits cleanly (log flushed, pty file removed) on SIGTERM, SIGINT or SIGHUP,
 * and also when its parent process goes away (so a killed test run leaves no emulator
 * behind).
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <getopt.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_io.h"
#include "sim_irq.h"
#include "sim_cycle_timers.h"
#include "avr_ioport.h"
#include "avr_uart.h"
#include "uart_pty.h"

/* the accessors of uart_pty's FIFOs (the type is declared in uart_pty.h) */
DEFINE_FIFO(uint8_t, uart_pty_fifo);

/* host-side serial line: 115200 baud 8N1 = 10 bits per byte */
#define HOST_BAUD 115200u
#define HOST_BITS_PER_BYTE 10u

static volatile sig_atomic_t stop_requested;

static avr_t *avr;
static FILE *log_file;
static int log_uart = 1;
static uart_pty_t pty;
static avr_irq_t *uart_input_irq;
static int uart_xoff;                 /* the UART's input FIFO is full */
static avr_cycle_count_t byte_cycles; /* host byte time in cycles */

/* the output pins we watch */
struct pin {
	const char *name;
	char port;
	int bit;
	int last;
};
static struct pin pins[] = {
	{"OC1A", 'B', 1, 0}, /* square wave, Timer1 compare output A */
	{"CH1", 'D', 6, 0},  /* start pulse channel 1 (VTS) */
	{"CH2", 'D', 7, 0},  /* start pulse channel 2 (SPECT) */
};

static void on_signal(int sig)
{
	(void)sig;
	stop_requested = 1;
}

static void log_line(const char *what, unsigned value, int hex)
{
	if (!log_file)
		return;
	if (hex)
		fprintf(log_file, "%llu %s %02x\n", (unsigned long long)avr->cycle, what, value);
	else
		fprintf(log_file, "%llu %s %u\n", (unsigned long long)avr->cycle, what, value);
	fflush(log_file);
}

/* pin IRQ hook: simavr may raise a pin with the same level twice (with or without its
 * AVR_IOPORT_OUTPUT flag), so de-duplicate on the level itself */
static void pin_hook(avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	struct pin *p = param;
	int level = (value & 0xff) ? 1 : 0;
	if (level == p->last)
		return;
	p->last = level;
	log_line(p->name, (unsigned)level, 0);
}

static unsigned long tx_dropped;

/* device -> host: straight into the pty master from the simulation thread (uart_pty's
 * own thread would only notice the byte when its 0.5 ms select() times out) */
static void uart_tx_hook(avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	(void)param;
	uint8_t b = value & 0xff;
	if (log_uart)
		log_line("TX", b, 1);
	/* non-blocking: a host that reads nothing fills the pty (several KB), then bytes
	 * are dropped, as a USB serial bridge with nobody reading would */
	if (write(pty.pty.s, &b, 1) != 1)
		tx_dropped++;
}

static void uart_xoff_hook(avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	(void)param;
	uart_xoff = value ? 1 : 0;
}

static void uart_xon_hook(avr_irq_t *irq, uint32_t value, void *param)
{
	(void)irq;
	(void)param;
	if (value)
		uart_xoff = 0;
}

/* UCSR0B bit 4 is RXEN0: a real UART drops what arrives before it is enabled, so hold
 * bytes back until the firmware has enabled its receiver */
#define UCSR0B_ADDR 0xC1
#define RXEN0_BIT 4

/* one host byte per byte time, on the simulation thread */
static avr_cycle_count_t inject_timer(avr_t *a, avr_cycle_count_t when, void *param)
{
	(void)param;
	int rx_enabled = (a->data[UCSR0B_ADDR] >> RXEN0_BIT) & 1;
	if (rx_enabled && !uart_xoff && !uart_pty_fifo_isempty(&pty.pty.out)) {
		uint8_t b = uart_pty_fifo_read(&pty.pty.out);
		if (log_uart)
			log_line("RX", b, 1);
		avr_raise_irq(uart_input_irq, b);
	}
	return when + byte_cycles;
}

/* simavr calls this while the firmware sleeps; we pace in the main loop instead */
static void no_sleep(avr_t *a, avr_cycle_count_t how_long)
{
	(void)a;
	(void)how_long;
}

static double now_s(void)
{
	struct timespec ts;
	clock_gettime(CLOCK_MONOTONIC, &ts);
	return ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* sleep until an absolute CLOCK_MONOTONIC time (no accumulated sleep overshoot) */
static void sleep_until_s(double t)
{
	struct timespec ts = {(time_t)t, (long)((t - (time_t)t) * 1e9)};
	while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR && !stop_requested)
		;
}

/* write a small file atomically (tmp + rename), so a reader never sees half of it */
static int write_file_atomic(const char *path, const char *text)
{
	char tmp[4096];
	snprintf(tmp, sizeof tmp, "%s.tmp%d", path, (int)getpid());
	FILE *f = fopen(tmp, "w");
	if (!f)
		return -1;
	fputs(text, f);
	if (fclose(f) != 0)
		return -1;
	return rename(tmp, path);
}

static void write_status(int fd, avr_cycle_count_t cycle)
{
	char buf[32];
	int n = snprintf(buf, sizeof buf, "%020llu\n", (unsigned long long)cycle);
	if (pwrite(fd, buf, (size_t)n, 0) < 0) {
		/* a status file is a convenience; ignore a failed write */
	}
}

static void usage(const char *argv0)
{
	fprintf(stderr,
		"usage: %s --edges FILE [--pty-file FILE] [--status FILE] [--speed X]\n"
		"          [--mcu NAME] [--freq HZ] [--no-uart-log] FIRMWARE.elf\n"
		"  --speed X   emulated seconds per wall second (default 1 = real time; 0 = as fast as possible)\n",
		argv0);
}

int main(int argc, char **argv)
{
	const char *edges_path = NULL, *pty_path_file = NULL, *status_path = NULL;
	const char *mcu = "atmega328p";
	unsigned long freq = 16000000UL;
	double speed = 1.0;

	static const struct option opts[] = {
		{"edges", required_argument, 0, 'e'},
		{"pty-file", required_argument, 0, 'p'},
		{"status", required_argument, 0, 's'},
		{"speed", required_argument, 0, 'x'},
		{"mcu", required_argument, 0, 'm'},
		{"freq", required_argument, 0, 'f'},
		{"no-uart-log", no_argument, 0, 'n'},
		{"help", no_argument, 0, 'h'},
		{0, 0, 0, 0},
	};
	int c;
	while ((c = getopt_long(argc, argv, "e:p:s:x:m:f:nh", opts, NULL)) != -1) {
		switch (c) {
		case 'e': edges_path = optarg; break;
		case 'p': pty_path_file = optarg; break;
		case 's': status_path = optarg; break;
		case 'x': speed = strtod(optarg, NULL); break;
		case 'm': mcu = optarg; break;
		case 'f': freq = strtoul(optarg, NULL, 10); break;
		case 'n': log_uart = 0; break;
		default: usage(argv[0]); return c == 'h' ? 0 : 2;
		}
	}
	if (optind != argc - 1 || !edges_path || speed < 0) {
		usage(argv[0]);
		return 2;
	}
	const char *elf_path = argv[optind];

	/* signals: handled on this thread only (the pty thread inherits a blocked mask) */
	struct sigaction sa;
	memset(&sa, 0, sizeof sa);
	sa.sa_handler = on_signal;
	sigemptyset(&sa.sa_mask);
	sigaction(SIGTERM, &sa, NULL);
	sigaction(SIGINT, &sa, NULL);
	sigaction(SIGHUP, &sa, NULL);
	signal(SIGPIPE, SIG_IGN);
	sigset_t block, old;
	sigemptyset(&block);
	sigaddset(&block, SIGTERM);
	sigaddset(&block, SIGINT);
	sigaddset(&block, SIGHUP);

	elf_firmware_t fw;
	memset(&fw, 0, sizeof fw);
	if (elf_read_firmware(elf_path, &fw) != 0) {
		fprintf(stderr, "tbsim: cannot read firmware %s\n", elf_path);
		return 1;
	}
	avr = avr_make_mcu_by_name(mcu);
	if (!avr) {
		fprintf(stderr, "tbsim: unknown mcu %s\n", mcu);
		return 1;
	}
	avr_init(avr);
	avr->log = LOG_ERROR;
	avr_load_firmware(avr, &fw);
	avr->frequency = (uint32_t)freq; /* after loading: the ELF may carry its own */
	avr->sleep = no_sleep;

	log_file = fopen(edges_path, "w");
	if (!log_file) {
		fprintf(stderr, "tbsim: cannot write %s: %s\n", edges_path, strerror(errno));
		return 1;
	}
	fprintf(log_file, "# tbsim %s %s %lu Hz\n", elf_path, mcu, freq);
	fflush(log_file);

	for (size_t i = 0; i < sizeof pins / sizeof pins[0]; i++) {
		avr_irq_t *irq = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(pins[i].port), pins[i].bit);
		if (!irq) {
			fprintf(stderr, "tbsim: no pin P%c%d\n", pins[i].port, pins[i].bit);
			return 1;
		}
		avr_irq_register_notify(irq, pin_hook, &pins[i]);
	}

	/* UART0: no console dump, no usleep() when the firmware polls the status register */
	uint32_t flags = 0;
	avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
	flags &= ~(uint32_t)(AVR_UART_FLAG_STDIO | AVR_UART_FLAG_POLL_SLEEP);
	avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);

	/* the pty; its reader thread must not take our signals */
	pthread_sigmask(SIG_BLOCK, &block, &old);
	uart_pty_init(avr, &pty);
	pthread_sigmask(SIG_SETMASK, &old, NULL);
	if (!pty.pty.s) {
		fprintf(stderr, "tbsim: cannot create a pty\n");
		return 1;
	}
	/* the line is raw in both directions (no echo, no CR/LF mapping) until the host
	 * program sets its own mode; uart_pty keeps the slave open, so reads never see EIO */
	struct termios tio;
	if (tcgetattr(pty.pty.s, &tio) == 0) {
		cfmakeraw(&tio);
		tcsetattr(pty.pty.s, TCSANOW, &tio);
	}

	avr_irq_t *uart_out = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT);
	uart_input_irq = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
	avr_irq_t *uart_xon = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON);
	avr_irq_t *uart_xoff_irq = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF);
	if (!uart_out || !uart_input_irq) {
		fprintf(stderr, "tbsim: no UART0\n");
		return 1;
	}
	/* device -> host: uart_tx_hook writes the master directly (not through uart_pty) */
	int fl = fcntl(pty.pty.s, F_GETFL);
	fcntl(pty.pty.s, F_SETFL, fl | O_NONBLOCK);
	avr_irq_register_notify(uart_out, uart_tx_hook, NULL);
	if (uart_xon)
		avr_irq_register_notify(uart_xon, uart_xon_hook, NULL);
	if (uart_xoff_irq)
		avr_irq_register_notify(uart_xoff_irq, uart_xoff_hook, NULL);

	byte_cycles = ((avr_cycle_count_t)avr->frequency * HOST_BITS_PER_BYTE + HOST_BAUD - 1) / HOST_BAUD;
	avr_cycle_timer_register(avr, byte_cycles, inject_timer, NULL);

	int status_fd = -1;
	if (status_path)
		status_fd = open(status_path, O_WRONLY | O_CREAT | O_TRUNC, 0644);

	if (pty_path_file) {
		char text[128];
		snprintf(text, sizeof text, "%s\n", pty.pty.slavename);
		if (write_file_atomic(pty_path_file, text) != 0) {
			fprintf(stderr, "tbsim: cannot write %s: %s\n", pty_path_file, strerror(errno));
			return 1;
		}
	}
	printf("PTY %s\n", pty.pty.slavename);
	fflush(stdout);

	/* the simulation loop: run, and sleep whenever we are ahead of the wall clock. Checked
	 * every 0.2 ms of emulated time (about 15 us of host time), so the emulated clock
	 * stays within ~0.2 ms of the wall clock whenever the host gives us the CPU (5000
	 * short sleeps a second); the kernel's timer slack (50 us by default) is cut so that
	 * the sleeps end on time. */
	prctl(PR_SET_TIMERSLACK, 1UL, 0, 0, 0);
	const avr_cycle_count_t check_every = avr->frequency / 5000; /* 0.2 ms emulated */
	const double ahead_slack_s = 0.00002;
	double t0 = now_s();
	avr_cycle_count_t c0 = avr->cycle;
	/* the host-time anchor of the pacing: cycle c0 is due at t0, cycle c at
	 * t0 + (c - c0) / frequency / speed (CLOCK_REALTIME epoch seconds and CLOCK_MONOTONIC) */
	struct timespec rt0;
	clock_gettime(CLOCK_REALTIME, &rt0);
	fprintf(log_file, "# t0 %llu %.9f %.9f %.9g\n", (unsigned long long)c0,
		rt0.tv_sec + rt0.tv_nsec * 1e-9, t0, speed);
	fflush(log_file);
	avr_cycle_count_t next_check = c0 + check_every;
	double next_status = t0;
	const pid_t parent = getppid();
	int state = cpu_Running;
	int rc = 0;

	while (!stop_requested) {
		state = avr_run(avr);
		if (state == cpu_Done || state == cpu_Crashed) {
			fprintf(stderr, "tbsim: firmware %s at cycle %llu (pc 0x%04x)\n",
				state == cpu_Done ? "stopped" : "crashed",
				(unsigned long long)avr->cycle, (unsigned)avr->pc);
			rc = state == cpu_Crashed ? 3 : 0;
			break;
		}
		if (avr->cycle < next_check)
			continue;
		next_check = avr->cycle + check_every;
		double wall = now_s();
		if (speed > 0) {
			double due = t0 + (double)(avr->cycle - c0) / avr->frequency / speed;
			if (due - wall > ahead_slack_s)
				sleep_until_s(due);
		}
		if (wall >= next_status) {
			if (status_fd >= 0)
				write_status(status_fd, avr->cycle);
			if (getppid() != parent) {
				fprintf(stderr, "tbsim: parent process gone, exiting\n");
				break;
			}
			next_status = wall + 0.005;
		}
	}

	if (status_fd >= 0) {
		write_status(status_fd, avr->cycle);
		close(status_fd);
	}
	if (tx_dropped)
		fprintf(stderr, "tbsim: %lu bytes to the host dropped (nobody reading)\n", tx_dropped);
	fprintf(log_file, "# end %llu\n", (unsigned long long)avr->cycle);
	fclose(log_file);
	log_file = NULL;
	if (pty_path_file)
		unlink(pty_path_file);
	/* closing the master makes the host side see the device vanish */
	close(pty.pty.s);
	fflush(stdout);
	_exit(rc);
}
