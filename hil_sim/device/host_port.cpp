#include "device/host_port.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <termios.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>

namespace icgt::sim {
namespace {

class PtyPort final : public HostPort {
 public:
  explicit PtyPort(std::string link) : link_(std::move(link)) {}
  ~PtyPort() override {
    close_master();
    ::unlink(link_.c_str());
  }

  bool open_pty(std::string& error) {
    master_ = ::posix_openpt(O_RDWR | O_NOCTTY | O_NONBLOCK);
    if (master_ < 0 || ::grantpt(master_) != 0 || ::unlockpt(master_) != 0) {
      error = std::string("posix_openpt: ") + std::strerror(errno);
      return false;
    }
    const char* slave = ::ptsname(master_);
    if (slave == nullptr) {
      error = "ptsname failed";
      return false;
    }
    // Raw mode on the slave side now, so nothing the device writes before the host has
    // configured the port is mangled by the line discipline (echo, CR/LF translation).
    const int s = ::open(slave, O_RDWR | O_NOCTTY);
    if (s >= 0) {
      termios t{};
      if (::tcgetattr(s, &t) == 0) {
        ::cfmakeraw(&t);
        (void)::tcsetattr(s, TCSANOW, &t);
      }
      ::close(s);
    }
    ::unlink(link_.c_str());
    if (::symlink(slave, link_.c_str()) != 0) {
      error = "symlink " + link_ + ": " + std::strerror(errno);
      return false;
    }
    return true;
  }

  std::size_t read_some(uint8_t* out, std::size_t cap) override {
    if (master_ < 0) return 0;
    const ssize_t n = ::read(master_, out, cap);
    return n > 0 ? static_cast<std::size_t>(n) : 0;
  }

  std::size_t write_some(const uint8_t* data, std::size_t len) override {
    if (!connected()) return 0;  // bytes written with no reader would reach the next host
    const ssize_t n = ::write(master_, data, len);
    return n > 0 ? static_cast<std::size_t>(n) : 0;
  }

  bool connected() override {
    if (master_ < 0) return false;
    // The master reports POLLHUP while no process has the slave open. open_pty() opened
    // and closed the slave once, so "never opened" reads as hung up too.
    pollfd p{master_, POLLIN, 0};
    (void)::poll(&p, 1, 0);
    return (p.revents & POLLHUP) == 0;
  }

  void unplug() override {
    close_master();
    ::unlink(link_.c_str());
  }

  void replug() override {
    std::string error;
    if (master_ < 0) (void)open_pty(error);
  }

  std::string url() const override { return link_; }
  int readable_fd() const override { return master_; }

 private:
  void close_master() {
    if (master_ >= 0) ::close(master_);
    master_ = -1;
  }
  std::string link_;
  int master_ = -1;
};

class TcpPort final : public HostPort {
 public:
  ~TcpPort() override {
    drop_client();
    if (listen_ >= 0) ::close(listen_);
  }

  bool listen_on(uint16_t port, std::string& error) {
    listen_ = ::socket(AF_INET, SOCK_STREAM | SOCK_NONBLOCK, 0);
    const int one = 1;
    (void)::setsockopt(listen_, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    a.sin_port = htons(port);
    if (listen_ < 0 || ::bind(listen_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 || ::listen(listen_, 1) != 0) {
      error = std::string("tcp listen: ") + std::strerror(errno);
      return false;
    }
    socklen_t len = sizeof a;
    (void)::getsockname(listen_, reinterpret_cast<sockaddr*>(&a), &len);
    port_ = ntohs(a.sin_port);
    return true;
  }

  std::size_t read_some(uint8_t* out, std::size_t cap) override {
    if (!connected()) return 0;
    const ssize_t n = ::recv(client_, out, cap, 0);
    if (n == 0 || (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK)) {
      drop_client();
      return 0;
    }
    return n > 0 ? static_cast<std::size_t>(n) : 0;
  }

  std::size_t write_some(const uint8_t* data, std::size_t len) override {
    if (!connected()) return 0;
    const ssize_t n = ::send(client_, data, len, MSG_NOSIGNAL);
    if (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK) drop_client();
    return n > 0 ? static_cast<std::size_t>(n) : 0;
  }

  bool connected() override {
    if (client_ < 0 && !unplugged_) {
      client_ = ::accept4(listen_, nullptr, nullptr, SOCK_NONBLOCK);
      if (client_ >= 0) {
        const int one = 1;
        (void)::setsockopt(client_, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
      }
    }
    return client_ >= 0;
  }

  void unplug() override {
    drop_client();
    unplugged_ = true;
  }
  void replug() override { unplugged_ = false; }
  std::string url() const override { return "socket://127.0.0.1:" + std::to_string(port_); }
  int readable_fd() const override { return client_; }

 private:
  void drop_client() {
    if (client_ >= 0) ::close(client_);
    client_ = -1;
  }
  int listen_ = -1;
  int client_ = -1;
  uint16_t port_ = 0;
  bool unplugged_ = false;
};

}  // namespace

std::unique_ptr<HostPort> open_pty_port(const std::string& symlink_path, std::string& error) {
  std::string link = symlink_path;
  if (link.empty()) link = "/tmp/icgt-sim-device-" + std::to_string(::getpid());
  auto port = std::make_unique<PtyPort>(link);
  if (!port->open_pty(error)) return nullptr;
  return port;
}

std::unique_ptr<HostPort> open_tcp_port(uint16_t port_number, std::string& error) {
  auto port = std::make_unique<TcpPort>();
  if (!port->listen_on(port_number, error)) return nullptr;
  return port;
}

}  // namespace icgt::sim
