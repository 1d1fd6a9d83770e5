#include "face_reenact/stream/udp.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netdb.h>
#include <unistd.h>

#include <cerrno>
#include <charconv>
#include <cstring>

#include "face_reenact/common/error.h"

namespace face_reenact::stream {
namespace {


uint16_t parse_port(const std::string& text, const std::string& what, const std::string& whole) {
  unsigned value = 0;
  auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (text.empty() || ec != std::errc() || end != text.data() + text.size() || value > 65535)
    throw Error(what + " '" + whole + "': '" + text + "' is not a port number (0-65535)");
  return static_cast<uint16_t>(value);
}

// Splits "HOST:PORT" / "[V6]:PORT".
void split_host_port(const std::string& text, const std::string& what, std::string* host, std::string* port) {
  if (!text.empty() && text[0] == '[') {
    const size_t close = text.find(']');
    if (close == std::string::npos || close + 1 >= text.size() || text[close + 1] != ':')
      throw Error(what + " '" + text + "': expected [IPV6]:PORT");
    *host = text.substr(1, close - 1);
    *port = text.substr(close + 2);
    return;
  }
  const size_t colon = text.rfind(':');
  if (colon == std::string::npos) throw Error(what + " '" + text + "': expected HOST:PORT");
  *host = text.substr(0, colon);
  *port = text.substr(colon + 1);
  if (host->find(':') != std::string::npos)
    throw Error(what + " '" + text + "': write IPv6 addresses as [ADDRESS]:PORT");
  if (host->empty()) throw Error(what + " '" + text + "': missing host before ':'");
}

in_addr parse_ipv4(const std::string& text, const std::string& what) {
  in_addr a{};
  if (::inet_pton(AF_INET, text.c_str(), &a) != 1)
    throw Error(what + ": '" + text + "' is not an IPv4 address");
  return a;
}

}  // namespace

bool UdpEndpoint::is_ipv4_multicast() const {
  if (address.ss_family != AF_INET) return false;
  const auto* sin = reinterpret_cast<const sockaddr_in*>(&address);
  return IN_MULTICAST(ntohl(sin->sin_addr.s_addr));
}

uint16_t UdpEndpoint::port() const {
  if (address.ss_family == AF_INET) return ntohs(reinterpret_cast<const sockaddr_in*>(&address)->sin_port);
  if (address.ss_family == AF_INET6) return ntohs(reinterpret_cast<const sockaddr_in6*>(&address)->sin6_port);
  return 0;
}

std::string UdpEndpoint::numeric() const {
  char buf[INET6_ADDRSTRLEN] = {0};
  if (address.ss_family == AF_INET) {
    ::inet_ntop(AF_INET, &reinterpret_cast<const sockaddr_in*>(&address)->sin_addr, buf, sizeof(buf));
    return std::string(buf) + ":" + std::to_string(port());
  }
  if (address.ss_family == AF_INET6) {
    ::inet_ntop(AF_INET6, &reinterpret_cast<const sockaddr_in6*>(&address)->sin6_addr, buf, sizeof(buf));
    return "[" + std::string(buf) + "]:" + std::to_string(port());
  }
  return "?";
}

UdpEndpoint resolve_endpoint(const std::string& host_port, const std::string& what) {
  std::string host, port_text;
  split_host_port(host_port, what, &host, &port_text);
  const uint16_t port = parse_port(port_text, what, host_port);
  if (port == 0) throw Error(what + " '" + host_port + "': port 0 is not a destination");
  addrinfo hints{};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_DGRAM;
  hints.ai_protocol = IPPROTO_UDP;
  hints.ai_flags = AI_ADDRCONFIG;
  addrinfo* res = nullptr;
  int rc = ::getaddrinfo(host.c_str(), port_text.c_str(), &hints, &res);
  if (rc == EAI_BADFLAGS || (rc != 0 && rc != EAI_NONAME && rc != EAI_AGAIN)) {
    hints.ai_flags = 0;
    rc = ::getaddrinfo(host.c_str(), port_text.c_str(), &hints, &res);
  }
  if (rc != 0 || !res)
    throw Error(what + " '" + host_port + "': cannot resolve host '" + host + "': " + ::gai_strerror(rc));
  UdpEndpoint ep;
  // Prefer IPv4 (multicast and most LANs), else the first answer.
  const addrinfo* pick = res;
  for (const addrinfo* a = res; a; a = a->ai_next)
    if (a->ai_family == AF_INET) {
      pick = a;
      break;
    }
  std::memcpy(&ep.address, pick->ai_addr, pick->ai_addrlen);
  ep.length = pick->ai_addrlen;
  ep.text = host_port;
  ::freeaddrinfo(res);
  return ep;
}

ListenSpec parse_listen_spec(const std::string& text, const std::string& what) {
  ListenSpec spec;
  if (text.find(':') == std::string::npos) {
    spec.port = parse_port(text, what, text);
    return spec;
  }
  std::string host, port_text;
  split_host_port(text, what, &host, &port_text);
  spec.port = parse_port(port_text, what, text);
  const in_addr a = parse_ipv4(host, what + " '" + text + "'");
  spec.address = host;
  spec.multicast = IN_MULTICAST(ntohl(a.s_addr));
  if (spec.multicast && spec.port == 0)
    throw Error(what + " '" + text + "': a multicast group needs an explicit port");
  return spec;
}

UdpSocket& UdpSocket::operator=(UdpSocket&& o) noexcept {
  if (this != &o) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = o.fd_;
    o.fd_ = -1;
  }
  return *this;
}

UdpSocket::~UdpSocket() {
  if (fd_ >= 0) ::close(fd_);
}

UdpSocket UdpSocket::open_receiver(const ListenSpec& spec, const std::string& multicast_interface,
                                   int receive_buffer_bytes) {
  const std::string where = spec.address + ":" + std::to_string(spec.port);
  UdpSocket s(::socket(AF_INET, SOCK_DGRAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0));
  if (s.fd_ < 0) throw Error("cannot create a UDP socket: " + errno_text(errno));
  const int one = 1;
  if (spec.multicast) {
    // Several receivers on one machine (several targets) may share a group's port.
    ::setsockopt(s.fd_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one));
  }
  if (receive_buffer_bytes > 0)
    ::setsockopt(s.fd_, SOL_SOCKET, SO_RCVBUF, &receive_buffer_bytes, sizeof(receive_buffer_bytes));
  // Ask the kernel to report how many datagrams it dropped for lack of buffer space.
  ::setsockopt(s.fd_, SOL_SOCKET, SO_RXQ_OVFL, &one, sizeof(one));
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(spec.port);
  addr.sin_addr = parse_ipv4(spec.address, "listen address");
  if (::bind(s.fd_, reinterpret_cast<const sockaddr*>(&addr), sizeof(addr)) != 0)
    throw Error("cannot listen on UDP " + where + ": " + errno_text(errno));
  if (spec.multicast) {
    ip_mreq mreq{};
    mreq.imr_multiaddr = addr.sin_addr;
    mreq.imr_interface.s_addr = htonl(INADDR_ANY);
    if (!multicast_interface.empty())
      mreq.imr_interface = parse_ipv4(multicast_interface, "multicast interface");
    if (::setsockopt(s.fd_, IPPROTO_IP, IP_ADD_MEMBERSHIP, &mreq, sizeof(mreq)) != 0)
      throw Error("cannot join multicast group " + spec.address + " on interface " +
                  (multicast_interface.empty() ? std::string("(default)") : multicast_interface) + ": " +
                  errno_text(errno));
  }
  return s;
}

UdpSocket UdpSocket::open_sender(const UdpEndpoint& to, const MulticastSendOptions& multicast) {
  UdpSocket s(::socket(to.address.ss_family, SOCK_DGRAM | SOCK_CLOEXEC, 0));
  if (s.fd_ < 0) throw Error("cannot create a UDP socket: " + errno_text(errno));
  if (to.is_ipv4_multicast()) {
    if (multicast.ttl < 0 || multicast.ttl > 255) throw Error("multicast TTL must be 0-255");
    const int ttl = multicast.ttl;
    const int loop = multicast.loopback ? 1 : 0;
    if (::setsockopt(s.fd_, IPPROTO_IP, IP_MULTICAST_TTL, &ttl, sizeof(ttl)) != 0 ||
        ::setsockopt(s.fd_, IPPROTO_IP, IP_MULTICAST_LOOP, &loop, sizeof(loop)) != 0)
      throw Error("cannot set multicast options: " + errno_text(errno));
    if (!multicast.interface_address.empty()) {
      in_addr ifaddr = parse_ipv4(multicast.interface_address, "multicast interface");
      if (::setsockopt(s.fd_, IPPROTO_IP, IP_MULTICAST_IF, &ifaddr, sizeof(ifaddr)) != 0)
        throw Error("cannot send multicast on interface " + multicast.interface_address + ": " +
                    errno_text(errno));
    }
  }
  if (::connect(s.fd_, reinterpret_cast<const sockaddr*>(&to.address), to.length) != 0)
    throw Error("cannot send to " + to.text + " (" + to.numeric() + "): " + errno_text(errno));
  return s;
}

uint16_t UdpSocket::local_port() const {
  sockaddr_storage a{};
  socklen_t len = sizeof(a);
  if (::getsockname(fd_, reinterpret_cast<sockaddr*>(&a), &len) != 0) return 0;
  if (a.ss_family == AF_INET) return ntohs(reinterpret_cast<const sockaddr_in*>(&a)->sin_port);
  if (a.ss_family == AF_INET6) return ntohs(reinterpret_cast<const sockaddr_in6*>(&a)->sin6_port);
  return 0;
}

int UdpSocket::send(std::span<const uint8_t> datagram) const {
  for (;;) {
    const ssize_t n = ::send(fd_, datagram.data(), datagram.size(), MSG_NOSIGNAL);
    if (n >= 0) return 0;
    if (errno == EINTR) continue;
    return errno;
  }
}

}  // namespace face_reenact::stream
