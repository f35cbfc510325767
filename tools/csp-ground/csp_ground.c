/*
 * csp-ground: minimal libcsp "ground node" CLI for KISS interop tests.
 *
 * Opens a serial device (e.g. a socat pty) as a libcsp KISS interface, pings
 * a node, sends connectionless packets to it and prints every packet received
 * on a listen port as one machine-parseable line (format in README.md).
 *
 * Links libcsp (MIT licence), built from ../shared/vendor/libcsp by build.sh;
 * no libcsp code is copied here.
 */
#define _POSIX_C_SOURCE 200809L

#include <errno.h>
#include <getopt.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <csp/csp.h>
#include <csp/csp_debug.h>
#include <csp/drivers/usart.h>

#define PING_SIZE 16
#define MAX_PAYLOAD (CSP_BUFFER_SIZE - 4) /* csp_kiss_tx appends a CRC32 */

static struct timespec t_start;
static pthread_mutex_t out_lock = PTHREAD_MUTEX_INITIALIZER;
static csp_socket_t listen_sock = {.opts = CSP_SO_CONN_LESS};
static unsigned long listen_end_ms;
static int rx_count;

static unsigned long now_ms(void) {
	struct timespec t;
	clock_gettime(CLOCK_MONOTONIC, &t);
	return (unsigned long)((t.tv_sec - t_start.tv_sec) * 1000L + (t.tv_nsec - t_start.tv_nsec) / 1000000L);
}

static void sleep_ms(unsigned long ms) {
	struct timespec t = {.tv_sec = ms / 1000, .tv_nsec = (long)(ms % 1000) * 1000000L};
	while (nanosleep(&t, &t) != 0 && errno == EINTR) {
	}
}

/* One output line, flushed at once (stdout is parsed by a test). */
static void out(const char *fmt, ...) {
	va_list ap;
	va_start(ap, fmt);
	pthread_mutex_lock(&out_lock);
	vprintf(fmt, ap);
	fflush(stdout);
	pthread_mutex_unlock(&out_lock);
	va_end(ap);
}

/* Overrides libcsp's weak csp_print_func: keep its diagnostics off stdout. */
void csp_print_func(const char *fmt, ...) {
	va_list ap;
	va_start(ap, fmt);
	vfprintf(stderr, fmt, ap);
	va_end(ap);
}

static void *router_task(void *arg) {
	(void)arg;
	for (;;) {
		csp_route_work();
	}
	return NULL;
}

static void *rx_task(void *arg) {
	(void)arg;
	char hex[2 * CSP_BUFFER_SIZE + 1];
	unsigned long now;
	while ((now = now_ms()) < listen_end_ms) {
		csp_packet_t *p = csp_recvfrom(&listen_sock, (uint32_t)(listen_end_ms - now));
		if (p == NULL) {
			continue;
		}
		for (unsigned i = 0; i < p->length; i++) {
			snprintf(&hex[2 * i], 3, "%02x", p->data[i]);
		}
		hex[2 * p->length] = '\0';
		out("rx %lu %u %u %u %s\n", now_ms(), (unsigned)p->id.src, (unsigned)p->id.sport,
		    (unsigned)p->id.dport, hex);
		rx_count++;
		csp_buffer_free(p);
	}
	return NULL;
}

static void usage(void) {
	fprintf(stderr,
	        "usage: csp-ground --device PATH [--baud 115200] [--version 1|2] [--addr 1]\n"
	        "       [--node 10] [--pings 3] [--ping-timeout-ms 1000] [--listen-port 10]\n"
	        "       [--listen-ms 5000] [--send-port 11] [--gap-ms 100] [--send HEX]...\n");
	exit(2);
}

static long parse_num(const char *opt, const char *s, long min, long max) {
	char *end;
	errno = 0;
	long v = strtol(s, &end, 10);
	if (errno != 0 || end == s || *end != '\0' || v < min || v > max) {
		fprintf(stderr, "csp-ground: --%s: expected an integer in %ld..%ld, got '%s'\n", opt, min, max, s);
		exit(2);
	}
	return v;
}

static int hex_nibble(char c) {
	if (c >= '0' && c <= '9') return c - '0';
	if (c >= 'a' && c <= 'f') return c - 'a' + 10;
	if (c >= 'A' && c <= 'F') return c - 'A' + 10;
	return -1;
}

/* Decode HEX into buf (MAX_PAYLOAD bytes); returns the length or exits 2. */
static size_t parse_hex(const char *s, uint8_t *buf) {
	size_t n = strlen(s);
	if (n % 2 != 0 || n / 2 > MAX_PAYLOAD) {
		fprintf(stderr, "csp-ground: --send: need an even number of hex digits, at most %d bytes\n", MAX_PAYLOAD);
		exit(2);
	}
	for (size_t i = 0; i < n / 2; i++) {
		int hi = hex_nibble(s[2 * i]), lo = hex_nibble(s[2 * i + 1]);
		if (hi < 0 || lo < 0) {
			fprintf(stderr, "csp-ground: --send: bad hex '%s'\n", s);
			exit(2);
		}
		buf[i] = (uint8_t)(hi << 4 | lo);
	}
	return n / 2;
}

int main(int argc, char *argv[]) {
	clock_gettime(CLOCK_MONOTONIC, &t_start);

	const char *device = NULL;
	long baud = 115200, version = 2, addr = 1, node = 10, pings = 3, ping_timeout = 1000;
	long listen_port = 10, listen_ms = 5000, send_port = 11, gap_ms = 100;
	const char **sends = calloc((size_t)argc, sizeof(*sends));
	int n_sends = 0;
	if (sends == NULL) {
		return 1;
	}

	static const struct option opts[] = {
	    {"device", required_argument, 0, 'd'},      {"baud", required_argument, 0, 'b'},
	    {"version", required_argument, 0, 'v'},     {"addr", required_argument, 0, 'a'},
	    {"node", required_argument, 0, 'n'},        {"pings", required_argument, 0, 'p'},
	    {"ping-timeout-ms", required_argument, 0, 't'}, {"listen-port", required_argument, 0, 'l'},
	    {"listen-ms", required_argument, 0, 'L'},   {"send-port", required_argument, 0, 's'},
	    {"gap-ms", required_argument, 0, 'g'},      {"send", required_argument, 0, 'S'},
	    {0, 0, 0, 0}};
	int c;
	while ((c = getopt_long(argc, argv, "", opts, NULL)) != -1) {
		switch (c) {
			case 'd': device = optarg; break;
			case 'b': baud = parse_num("baud", optarg, 1, 4000000); break;
			case 'v': version = parse_num("version", optarg, 1, 2); break;
			case 'a': addr = parse_num("addr", optarg, 0, 16383); break;
			case 'n': node = parse_num("node", optarg, 0, 16383); break;
			case 'p': pings = parse_num("pings", optarg, 0, 100000); break;
			case 't': ping_timeout = parse_num("ping-timeout-ms", optarg, 0, 3600000); break;
			case 'l': listen_port = parse_num("listen-port", optarg, 0, CSP_PORT_MAX_BIND); break;
			case 'L': listen_ms = parse_num("listen-ms", optarg, 0, 86400000); break;
			case 's': send_port = parse_num("send-port", optarg, 0, 63); break;
			case 'g': gap_ms = parse_num("gap-ms", optarg, 0, 3600000); break;
			case 'S': sends[n_sends++] = optarg; break;
			default: usage();
		}
	}
	if (device == NULL || optind != argc) {
		usage();
	}
	long max_node = version == 1 ? 31 : 16383; /* 5-bit vs 14-bit host field */
	if (addr > max_node || node > max_node) {
		fprintf(stderr, "csp-ground: --addr/--node must be <= %ld with CSP v%ld\n", max_node, version);
		return 2;
	}
	static uint8_t payload[MAX_PAYLOAD];
	for (int i = 0; i < n_sends; i++) {
		parse_hex(sends[i], payload); /* validate all before touching the device */
	}

	/* The header version must be chosen before csp_init(). */
	csp_conf.version = (uint8_t)version;
	csp_init();

	csp_usart_conf_t uconf = {
	    .device = device, .baudrate = (uint32_t)baud, .databits = 8, .stopbits = 1, .paritysetting = 0};
	csp_iface_t *iface = NULL;
	int err = csp_usart_open_and_add_kiss_interface(&uconf, CSP_IF_KISS_DEFAULT_NAME, (uint16_t)addr, &iface);
	if (err != CSP_ERR_NONE) {
		fprintf(stderr, "csp-ground: cannot open KISS device %s (error %d)\n", device, err);
		return 2;
	}
	/* No routing table (CSP_USE_RTABLE off) and netmask 0: csp_send_direct()
	 * falls back to default interfaces, so this sends everything over KISS. */
	iface->is_default = 1;

	csp_listen(&listen_sock, CSP_CONN_RXQUEUE_LEN); /* creates the rx queue */
	if (csp_bind(&listen_sock, (uint8_t)listen_port) != CSP_ERR_NONE) {
		fprintf(stderr, "csp-ground: cannot bind port %ld\n", listen_port);
		return 2;
	}
	listen_end_ms = now_ms() + (unsigned long)listen_ms;

	pthread_t router, rx;
	if (pthread_create(&router, NULL, router_task, NULL) != 0 || pthread_detach(router) != 0 ||
	    pthread_create(&rx, NULL, rx_task, NULL) != 0) {
		fprintf(stderr, "csp-ground: pthread_create failed\n");
		return 1;
	}

	int pings_ok = 0;
	for (long i = 0; i < pings; i++) {
		int ms = csp_ping((uint16_t)node, (uint32_t)ping_timeout, PING_SIZE, CSP_O_NONE);
		if (ms >= 0) {
			pings_ok++;
			out("ping %ld ok %d\n", i, ms);
		} else {
			out("ping %ld fail\n", i);
		}
	}

	for (int i = 0; i < n_sends; i++) {
		size_t len = parse_hex(sends[i], payload);
		csp_packet_t *p = csp_buffer_get(len);
		if (p == NULL) {
			fprintf(stderr, "csp-ground: out of CSP buffers, send %d skipped\n", i);
		} else {
			memcpy(p->data, payload, len);
			p->length = (uint16_t)len;
			csp_sendto(CSP_PRIO_NORM, (uint16_t)node, (uint8_t)send_port, (uint8_t)listen_port, CSP_O_NONE, p);
			out("sent %d %zu\n", i, len);
		}
		sleep_ms((unsigned long)gap_ms);
	}

	pthread_join(rx, NULL);
	out("done pings_ok=%d rx=%d\n", pings_ok, rx_count);
	free(sends);
	return 0;
}
