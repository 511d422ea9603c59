#include "util/process.h"

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <csignal>
#include <cstring>

#include "util/error.h"

extern char** environ;

namespace refocus {

namespace {
constexpr size_t kKeep = 64 * 1024;

void close_fd(int& fd) {
    if (fd >= 0) ::close(fd);
    fd = -1;
}
}  // namespace

Subprocess::Subprocess(const std::vector<std::string>& argv) {
    if (argv.empty()) throw Error("no program to run");
    // A child that exits early must give us EPIPE, not kill us.
    std::signal(SIGPIPE, SIG_IGN);
    int in[2], out[2];
    if (::pipe2(in, O_CLOEXEC) != 0)
        throw Error(std::string("cannot create a pipe: ") + std::strerror(errno));
    if (::pipe2(out, O_CLOEXEC) != 0) {
        const int err = errno;
        ::close(in[0]);
        ::close(in[1]);
        throw Error(std::string("cannot create a pipe: ") + std::strerror(err));
    }
    posix_spawn_file_actions_t fa;
    posix_spawn_file_actions_init(&fa);
    posix_spawn_file_actions_adddup2(&fa, in[0], 0);
    posix_spawn_file_actions_adddup2(&fa, out[1], 1);
    posix_spawn_file_actions_adddup2(&fa, out[1], 2);
    std::vector<char*> args;
    for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    const int rc = ::posix_spawnp(&m_pid, args[0], &fa, nullptr, args.data(), environ);
    posix_spawn_file_actions_destroy(&fa);
    ::close(in[0]);
    ::close(out[1]);
    if (rc != 0) {
        ::close(in[1]);
        ::close(out[0]);
        m_pid = -1;
        throw Error("cannot start " + argv[0] + ": " + std::strerror(rc) +
                    (rc == ENOENT ? " (is it installed and on PATH?)" : ""));
    }
    m_stdin = in[1];
    m_out = out[0];
    m_reader = std::thread([this] {
        char buf[4096];
        for (;;) {
            const ssize_t n = ::read(m_out, buf, sizeof buf);
            if (n < 0 && errno == EINTR) continue;
            if (n <= 0) break;
            m_output.append(buf, size_t(n));
            if (m_output.size() > 2 * kKeep) m_output.erase(0, m_output.size() - kKeep);
        }
    });
}

Subprocess::~Subprocess() {
    if (m_pid > 0) {
        kill();
    }
    close_fd(m_stdin);
    if (m_reader.joinable()) m_reader.join();
    close_fd(m_out);
}

bool Subprocess::write_stdin(const void* data, size_t n) {
    const char* p = static_cast<const char*>(data);
    while (n > 0) {
        if (m_stdin < 0) {
            errno = EPIPE;
            return false;
        }
        const ssize_t w = ::write(m_stdin, p, n);
        if (w < 0) {
            if (errno == EINTR) continue;
            return false;
        }
        p += w;
        n -= size_t(w);
    }
    return true;
}

int Subprocess::wait() {
    close_fd(m_stdin);
    if (m_pid > 0) {
        int status = 0;
        while (::waitpid(m_pid, &status, 0) < 0 && errno == EINTR) {
        }
        m_pid = -1;
        m_status = WIFEXITED(status)     ? WEXITSTATUS(status)
                   : WIFSIGNALED(status) ? 128 + WTERMSIG(status)
                                         : 255;
    }
    if (m_reader.joinable()) m_reader.join();
    close_fd(m_out);
    if (m_output.size() > kKeep) m_output.erase(0, m_output.size() - kKeep);
    return m_status;
}

void Subprocess::kill() {
    if (m_pid > 0) ::kill(m_pid, SIGKILL);
    wait();
}

std::string Subprocess::last_line() const {
    size_t end = m_output.find_last_not_of("\r\n \t");
    if (end == std::string::npos) return "";
    size_t begin = m_output.find_last_of("\r\n", end);
    begin = begin == std::string::npos ? 0 : begin + 1;
    return m_output.substr(begin, end - begin + 1);
}

}  // namespace refocus
