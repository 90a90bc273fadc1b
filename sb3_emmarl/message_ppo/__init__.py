from sb3_emmarl.message_ppo.message_ppo import MessagePPO

__all__ = ["MessagePPO"]
